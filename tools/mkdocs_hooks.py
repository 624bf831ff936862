"""MkDocs hooks (mkdocs.yml ``hooks:``): the generated pages are made from the code at every
build, so the site cannot show a stale settings reference or results table."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent


def on_pre_build(config: Any, **_: Any) -> None:
    if str(TOOLS) not in sys.path:  # mkdocs loads hooks with its own path
        sys.path.insert(0, str(TOOLS))
    import readme_results
    import settings_reference

    page = Path(config["docs_dir"]) / "settings.md"
    text = settings_reference.render()
    if not page.is_file() or page.read_text(encoding="utf-8") != text:
        page.write_text(text, encoding="utf-8")
    readme_results.main([])
