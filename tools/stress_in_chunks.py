"""Run a stress sweep a few scenes at a time, so that a batch stopped early has whole scenes.

`sumo-swarm batch` starts the long runs first: every `swarm` run of a 200-scene sweep before any
`cacc` or `sumo-lc` run, so a sweep stopped early has no scene with all its runs and nothing to
report. This runs the same runs (same run ids: they depend on the overrides, not on the sweep
file) into the same batch folder, --chunk scenes at a time, in the sweep's order. Finish or
resume with the ordinary command on the full sweep file into the same folder: it finds the
finished runs and skips them.

Usage: python tools/stress_in_chunks.py [--version 2] [--chunk 6] --out DIR [--workers 2]
Then:  sumo-swarm batch scenarios/stress2.toml --out DIR --workers 2   (skips finished runs)
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from sumo_swarm.study.batch import run_batch

ROOT = Path(__file__).resolve().parent.parent


def _make_stress() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_stress", ROOT / "tools" / "make_stress.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--version", type=int, choices=(1, 2), default=2)
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--chunk", type=int, default=6, help="scenes per batch (default 6)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    ms = _make_stress()
    seed = ms.DEFAULT_SEED[args.version] if args.seed is None else args.seed
    cases = ms.draw(args.scenes, seed, args.version)
    # Beside the full sweep file: the same base and network paths, hence the same run ids.
    chunk_file = ROOT / "scenarios" / f".stress{args.version}-chunk.toml"
    try:
        for first in range(0, len(cases), args.chunk):
            part = cases[first : first + args.chunk]
            chunk_file.write_text(ms.render(part, seed, args.version), encoding="utf-8")
            report = run_batch(
                chunk_file, args.out, workers=args.workers, progress=False, impact=False
            )
            print(
                f"scenes {first + 1}-{first + len(part)} of {len(cases)}: "
                f"{report.ran} run now, {report.skipped} done before, {report.failed} failed",
                flush=True,
            )
    finally:
        chunk_file.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
