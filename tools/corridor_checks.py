"""The corridor checks of issue 51: the swarm against sumo-cacc and sumo-lc on corridors with the
CAVs inside the traffic, at each CAV share, judged by seven checks.

Roads: the real motorways of ``sumo_swarm.sim.userroads.OSM_ROADS`` (OpenStreetMap maps in
networks/osm/, netconverted as a user does, SUMO's default drivers, 15 % trucks, ramps) and the
project's own corridor (scenarios/corridor.toml, cut to the run's length, its
``corridor.cav_share`` set). Every run is what a user types, one process each::

    sumo-swarm run --sumocfg ROAD/user.sumocfg --cav-type cav --cav-share P
                   --cav-share-of passenger --controller C --seed S --out DIR
    sumo-swarm run corridor.toml --controller C --seed S --out DIR

at the step length 0.2 s for every controller (``--step``: another, every controller). ``P`` is
the share of passenger vehicles that makes the asked share of all vehicles CAVs, the trucks
keeping theirs. Per road and share, the checks (the swarm's run against the baselines'):

1. no collision of any vehicle (``safety.collisions``);
2. CAV mean speed >= sumo-cacc's and >= 0.97 x sumo-lc's (``cav.mean_speed_mps``);
3. throughput >= 0.98 x the better baseline's (``network.throughput_vph``);
4. mean delay of the vehicles that are not CAVs <= 1.05 x the better (lower) baseline's
   (``network.delay_s_others``);
5. TTC < 1.5 s conflicts <= the worse (higher) baseline's (``network.ttc_below_1_5s_events``);
6. smallest gap of a CAV behind a CAV >= 2 m (``cav.gap_min_cav_m``; no CAV ever behind a CAV
   passes);
7. aborted manoeuvres <= 10 % of those started (``swarms.overtakes_aborted / _started``).

A check that misses a value (a run failed, a baseline lacks the measure) is ``n/a`` and does not
pass. Results are never lost: a failed run is a row with its error, and a run whose
``summary.json`` exists is kept, not run again, unless ``--force``. Prints a line per finished
run, then the table (a row per road, share and seed: each controller's value side by side and
PASS/FAIL per check) and the checks passed; then each road and share with its seeds together
(issue 51 asks the checks "for each of these, at 20 % and 40 % CAVs"): the means over the seeds
(counts summed, the smallest CAV-CAV gap) judged the same way, and the share of seeds whose own
check passed. Writes it as ``--table``.md, .csv (a row per seed), .roads.csv (a row per road
and share) and .runs.csv::

    python tools/corridor_checks.py [--roads NAME ...] [--shares P ...] [--end S]
                                    [--seeds N ...] [--out DIR] [--workers N] [--force]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
import tomllib
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout: this tree's package, not an installed one

from sumo_swarm.sim.network import others_delay_s  # noqa: E402
from sumo_swarm.sim.userroads import (  # noqa: E402
    CAV_TYPE,
    OSM_ROADS,
    osm_cav_share_option,
    write_osm_road,
)

sys.path.insert(0, str(ROOT / "tools"))  # the users' roads tool, beside this one
from user_roads import git_commit, table_file  # noqa: E402

SWARM = "swarm"
BASELINES = ("sumo-cacc", "sumo-lc")
CONTROLLERS = (SWARM, *BASELINES)
CORRIDOR = "corridor"  # the project's own corridor
CORRIDOR_TOML = ROOT / "scenarios" / "corridor.toml"
OSM_DIR = ROOT / "networks" / "osm"
ROADS = (*OSM_ROADS, CORRIDOR)
DEFAULT_STEP_S = 0.2  # every controller's (--step)
STEP_LENGTH_S = DEFAULT_STEP_S

# The thresholds of issue 51's checks
SPEED_OF_LC = 0.97  # CAV mean speed >= this x sumo-lc's (and >= sumo-cacc's)
THROUGHPUT_OF_BEST = 0.98  # throughput >= this x the better baseline's
DELAY_OF_BEST = 1.05  # others' mean delay <= this x the better baseline's
MIN_CAV_GAP_M = 2.0  # smallest bumper-to-bumper gap of a CAV behind a CAV [m]
ABORTED_OF_STARTED = 0.10  # aborted manoeuvres <= this share of those started

PASS, FAIL, NA = "PASS", "FAIL", "n/a"


# --------------------------------------------------------------------------- measures and checks


def _get(summary: Mapping[str, Any], dotted: str) -> Any:
    value: Any = summary
    for key in dotted.split("."):
        if not isinstance(value, Mapping):
            return None
        value = value.get(key)
    return value


def measures(summary: Mapping[str, Any], run_dir: Path | None = None) -> dict[str, float | None]:
    """The measures the checks read, from a run's summary.json. A summary written before
    ``network.delay_s_others`` existed gets it from the run's ``network_trips.parquet``."""
    others = _get(summary, "network.delay_s_others")
    trips = None if run_dir is None else run_dir / "network_trips.parquet"
    if others is None and trips is not None and trips.is_file():
        others = others_delay_s(pd.read_parquet(trips))
    return {
        "collisions": _get(summary, "safety.collisions"),
        "cav_speed_mps": _get(summary, "cav.mean_speed_mps"),
        "throughput_vph": _get(summary, "network.throughput_vph"),
        "others_delay_s": others,
        "ttc_events": _get(summary, "network.ttc_below_1_5s_events"),
        "cav_cav_gap_min_m": _get(summary, "cav.gap_min_cav_m"),
        "started": _get(summary, "swarms.overtakes_started"),
        "aborted": _get(summary, "swarms.overtakes_aborted"),
        "cavs": _get(summary, "cav.count"),
    }


@dataclass(frozen=True)
class Check:
    """One check of a road and share: ``verdict`` PASS, FAIL or n/a, and why."""

    key: str
    title: str
    verdict: str
    detail: str


# key, title (a column of the table)
CHECKS = (
    ("collisions", "collisions = 0"),
    ("cav_speed", "CAV speed >= cacc, >= 0.97 lc [m/s]"),
    ("throughput", "throughput >= 0.98 best [veh/h]"),
    ("others_delay", "others' delay <= 1.05 best [s]"),
    ("ttc", "TTC < 1.5 s <= worst"),
    ("cav_gap", "CAV-CAV gap >= 2 m [m]"),
    ("aborted", "aborted <= 10 % started"),
)
TITLES = dict(CHECKS)


def _known(*values: float | None) -> bool:
    return all(v is not None and math.isfinite(float(v)) for v in values)


def judge(by_controller: Mapping[str, Mapping[str, float | None] | None]) -> list[Check]:
    """The seven checks of the swarm's measures against the baselines' (each a dict of
    :func:`measures`, None for a run that failed). A check missing a value is n/a."""
    swarm = by_controller.get(SWARM) or {}
    cacc = by_controller.get("sumo-cacc") or {}
    lc = by_controller.get("sumo-lc") or {}

    def check(key: str, ok: bool | None, detail: str) -> Check:
        verdict = NA if ok is None else (PASS if ok else FAIL)
        return Check(key, TITLES[key], verdict, detail)

    out = []
    n = swarm.get("collisions")
    out.append(
        check(
            "collisions",
            None if n is None else n == 0,
            "no swarm run" if n is None else f"swarm {_n(n)}",
        )
    )

    v, vc, vl = (m.get("cav_speed_mps") for m in (swarm, cacc, lc))
    ok = v >= vc and v >= SPEED_OF_LC * vl if _known(v, vc, vl) else None
    out.append(check("cav_speed", ok, f"{_f(v)} against {_f(vc)} and 0.97 x {_f(vl)}"))

    q, qc, ql = (m.get("throughput_vph") for m in (swarm, cacc, lc))
    if _known(q, qc, ql):
        best = max(qc, ql)
        ok = q >= THROUGHPUT_OF_BEST * best
        out.append(check("throughput", ok, f"{_n(q)} >= 0.98 x {_n(best)}"))
    else:
        out.append(check("throughput", None, "missing"))

    d, dc, dl = (m.get("others_delay_s") for m in (swarm, cacc, lc))
    if _known(d, dc, dl):
        best = min(dc, dl)
        ok = d <= DELAY_OF_BEST * best
        out.append(check("others_delay", ok, f"{_f(d)} <= 1.05 x {_f(best)}"))
    else:
        out.append(check("others_delay", None, "missing"))

    t, tc, tl = (m.get("ttc_events") for m in (swarm, cacc, lc))
    if _known(t, tc, tl):
        worst = max(tc, tl)
        out.append(check("ttc", t <= worst, f"{_n(t)} <= {_n(worst)}"))
    else:
        out.append(check("ttc", None, "missing"))

    g = swarm.get("cav_cav_gap_min_m")
    if not swarm:
        out.append(check("cav_gap", None, "missing"))
    elif g is None:  # no CAV was ever behind a CAV: nothing came closer than 2 m
        out.append(check("cav_gap", True, "no CAV behind a CAV"))
    else:
        out.append(check("cav_gap", g >= MIN_CAV_GAP_M, f"{_f(g)} m"))

    started, aborted = swarm.get("started"), swarm.get("aborted")
    if _known(started, aborted):
        ok = aborted <= ABORTED_OF_STARTED * started
        out.append(check("aborted", ok, f"{_n(aborted)} of {_n(started)}"))
    else:
        out.append(check("aborted", None, "missing"))
    return out


def _f(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _n(value: float | None) -> str:
    """A count (read back from a table as a float)."""
    return "-" if value is None else f"{value:.0f}"


# --------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class Job:
    road: str
    share: float
    seed: int
    controller: str
    args: tuple[str, ...]  # sumo-swarm run's arguments but --controller, --seed and --out
    out: Path  # the run's folder; its log is beside it (<out>.log)
    commit: str = ""  # of this checkout, in the log of a run made now


def corridor_toml(end_s: float, share: float) -> str:
    """scenarios/corridor.toml with ``simulation.duration_s`` = ``end_s`` and
    ``corridor.cav_share`` = ``share``, as TOML text."""
    data = tomllib.loads(CORRIDOR_TOML.read_text(encoding="utf-8"))
    data["simulation"]["duration_s"] = float(end_s)
    data["simulation"]["step_length_s"] = STEP_LENGTH_S
    data["corridor"]["cav_share"] = float(share)
    return toml_text(data)


def toml_text(data: Mapping[str, Any]) -> str:
    """A scenario file's tables (top-level keys first, then ``[section]``s of plain values)."""
    lines = [f"{k} = {_literal(v)}" for k, v in data.items() if not isinstance(v, Mapping)]
    for section, table in data.items():
        if isinstance(table, Mapping):
            lines += ["", f"[{section}]"]
            lines += [f"{k} = {_literal(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def _literal(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_literal(v) for v in value) + "]"
    if isinstance(value, int | float):
        return repr(value)
    raise TypeError(f"no TOML literal for {value!r}")


def share_name(share: float) -> str:
    return f"{share:.2f}"


def road_args(road: str, share: float, end_s: float, folder: Path) -> tuple[str, ...]:
    """Write ``road``'s files into ``folder`` for a run of ``end_s`` at the CAV share ``share``
    (of all vehicles); return ``sumo-swarm run``'s arguments for it."""
    folder.mkdir(parents=True, exist_ok=True)
    if road == CORRIDOR:
        toml = folder / f"corridor-{share_name(share)}.toml"
        toml.write_text(corridor_toml(end_s, share), encoding="utf-8")
        return (str(toml),)
    cfg = write_osm_road(road, OSM_DIR, folder, end_s=end_s, step_length_s=STEP_LENGTH_S)
    return (
        "--sumocfg", str(cfg), "--cav-type", CAV_TYPE,
        "--cav-share", repr(osm_cav_share_option(share)), "--cav-share-of", "passenger",
    )  # fmt: skip


def run_job(job: Job, *, force: bool, timeout_s: float) -> dict[str, Any]:
    """Run ``job`` as a user would (``sumo-swarm run``), or keep its earlier run (a
    ``summary.json`` in its folder, without ``force``); return its row."""
    row: dict[str, Any] = {"road": job.road, "share": job.share, "seed": job.seed}
    row["controller"] = job.controller
    summary_file = job.out / "summary.json"
    log = job.out.with_name(job.out.name + ".log")
    if summary_file.is_file() and not force:
        row.update(_finished(job, "kept"))
        first = log.read_text(encoding="utf-8").split("\n", 1)[0] if log.is_file() else ""
        row["run_commit"] = first.removeprefix("# commit ") if first.startswith("# commit ") else ""
        return row
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    cmd = [sys.executable, "-m", "sumo_swarm", "run", *job.args, "--controller", job.controller]
    cmd += ["--seed", str(job.seed), "--out", str(job.out)]
    if job.out.exists():  # an earlier run that failed, or --force: replace it
        cmd.append("--force")
    job.out.parent.mkdir(parents=True, exist_ok=True)
    summary_file.unlink(missing_ok=True)  # --force: a run that fails now must not read the last
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env)
    except subprocess.TimeoutExpired:
        row.update(status="failed", error=f"timeout after {timeout_s:g} s")
        row["process_s"] = round(time.perf_counter() - t0, 1)
        return row
    row["process_s"] = round(time.perf_counter() - t0, 1)
    row["run_commit"] = job.commit
    text = f"# commit {job.commit}\n" + " ".join(cmd) + "\n" + proc.stdout + proc.stderr
    log.write_text(text, encoding="utf-8")
    if proc.returncode != 0 and not summary_file.is_file():
        # the problem, not the notice of the options added that follows it
        lines = [
            line for line in proc.stderr.splitlines() if line.strip() and ": added --" not in line
        ]
        row.update(status="failed", error=f"exit {proc.returncode}: {lines[-1] if lines else ''}")
        return row
    row.update(_finished(job, "ran"))  # a run that ended but failed says why in its summary
    return row


def _finished(job: Job, how: str) -> dict[str, Any]:
    """The row of a run with a summary: its measures, or the error of an incomplete run."""
    try:
        summary = json.loads((job.out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return {"status": "failed", "error": f"summary.json unreadable: {exc}"}
    row: dict[str, Any] = {"status": how, "wall_s": _get(summary, "timing.wall_s")}
    # Its measures stay in the row (the runs' CSV), but a run that did not go to its end under
    # its controller is not judged.
    row.update(measures(summary, job.out))
    stood_down = summary.get("stood_down")
    if stood_down:
        at = stood_down.get("t_s") if isinstance(stood_down, Mapping) else None
        why = stood_down.get("reason") if isinstance(stood_down, Mapping) else stood_down
        error = f"the controller failed at {_f(at)} s and stood down ({why})"
        row.update(status="failed", error=error)
    elif not summary.get("complete", True):
        row.update(status="failed", error=f"incomplete: {summary.get('incomplete_reason')}")
    return row


# --------------------------------------------------------------------------- the table

# measure, column of the table, decimals
SHOWN = {
    "collisions": ("collisions", 0),
    "cav_speed": ("cav_speed_mps", 2),
    "throughput": ("throughput_vph", 0),
    "others_delay": ("others_delay_s", 1),
    "ttc": ("ttc_events", 0),
    "cav_gap": ("cav_cav_gap_min_m", 2),
}


def judged(runs: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per road, share and seed: the wide row (each controller's measures, each check's
    verdict and detail) for the CSV, and the table for a reader."""
    wide, shown = [], []
    for (road, share, seed), rows in runs.groupby(["road", "share", "seed"], sort=False):
        by = {}
        errors = []
        for row in rows.to_dict("records"):
            ok = row.get("status") in ("ran", "kept")
            by[row["controller"]] = {k: _clean(row.get(k)) for k in _MEASURE_KEYS} if ok else None
            if not ok:
                errors.append(f"{row['controller']}: {row.get('error', '')}")
        checks = judge(by)
        flat: dict[str, Any] = {"road": road, "share": share, "seed": seed}
        for c in CONTROLLERS:
            for k in _MEASURE_KEYS:
                flat[f"{k}.{c}"] = (by.get(c) or {}).get(k)
        for c in checks:
            flat[f"check.{c.key}"] = c.verdict
            flat[f"check.{c.key}.detail"] = c.detail
        flat["passed"] = sum(c.verdict == PASS for c in checks)
        flat["errors"] = "; ".join(errors)
        wide.append(flat)
        cells: dict[str, Any] = {"road": road, "CAV share": share_name(share), "seed": seed}
        for c in checks:
            if c.key in SHOWN:
                column, digits = SHOWN[c.key]
                values = " / ".join(
                    _cell((by.get(k) or {}).get(column), digits) for k in CONTROLLERS
                )
                cells[c.title] = f"{_mark(c.verdict)} {values}"
            else:  # aborted: the swarm's alone
                s = by.get(SWARM) or {}
                of = f"{_cell(s.get('aborted'), 0)} of {_cell(s.get('started'), 0)}"
                cells[c.title] = f"{_mark(c.verdict)} {of}"
        cells["passed"] = f"{flat['passed']}/{len(checks)}"
        cells["failed runs"] = flat["errors"]
        shown.append(cells)
    return pd.DataFrame(wide), pd.DataFrame(shown)


# How a road and share's seeds add up, per measure: summed (counts), the smallest (the gap),
# else the mean over the seeds.
_SUMMED = ("collisions", "ttc_events", "started", "aborted")
# The checks of the swarm's own measures, judged without a baseline.
_SWARM_ALONE = ("collisions", "cav_gap", "aborted")
# The measures the checks read (:func:`judge`).
_JUDGED_KEYS = ("collisions", "cav_speed_mps", "throughput_vph", "others_delay_s", "ttc_events",
                "cav_cav_gap_min_m", "started", "aborted")  # fmt: skip


def _over_seeds(values: list[float | None], key: str) -> float | None:
    known = [float(v) for v in values if v is not None]
    if key == "cav_cav_gap_min_m":
        return min(known) if known else None  # None: no CAV behind a CAV in any seed
    if len(known) != len(values) or not known:
        return None
    return sum(known) if key in _SUMMED else sum(known) / len(known)


def _measures_over(
    done: pd.DataFrame, controller: str, seeds, swarm_failed: bool
) -> dict[str, float | None] | None:
    """``controller``'s measures over ``seeds`` (:func:`_over_seeds`) from the runs that ran
    (``done``); None without any, or for the swarm when one of its runs failed."""
    mine = done[(done["controller"] == controller) & done["seed"].isin(seeds)]
    if mine.empty or (controller == SWARM and swarm_failed):
        return None
    return {
        k: _over_seeds([_clean(v) for v in mine.get(k, [None] * len(mine))], k)
        for k in _JUDGED_KEYS
    }


def judged_by_road(runs: pd.DataFrame, wide: pd.DataFrame) -> pd.DataFrame:
    """Per road and share, the seven checks of the seeds taken together (issue 51: "for each
    of these, at 20 % and 40 % CAVs"): each controller's measures over the seeds where every
    controller ran (means; counts summed; the smallest CAV-CAV gap), and per check the share
    of those seeds whose own check passed. The checks of the swarm alone (collisions, CAV-CAV
    gap, aborted) take every seed the swarm ran in. A "better" or "worse" baseline is the
    controller that is so over the seeds (its mean, or its sum). A swarm run that failed in any
    seed leaves nothing to judge (every check n/a): a road is not passed on the seeds that
    happened to run."""
    rows = []
    for (road, share), group in runs.groupby(["road", "share"], sort=False):
        ok = group["status"].isin(("ran", "kept"))
        seeds = [
            seed for seed, r in group[ok].groupby("seed", sort=False)
            if set(r["controller"]) >= set(CONTROLLERS)
        ]  # fmt: skip
        swarm_failed = bool(((group["controller"] == SWARM) & ~ok).any())
        done = group[ok]
        compared = judge({c: _measures_over(done, c, seeds, swarm_failed) for c in CONTROLLERS})
        alone = judge({SWARM: _measures_over(done, SWARM, done["seed"].unique(), swarm_failed)})
        checks = [a if a.key in _SWARM_ALONE else c for c, a in zip(compared, alone, strict=True)]
        cells = wide[(wide["road"] == road) & (wide["share"] == share)]
        row: dict[str, Any] = {"road": road, "share": share, "seeds": len(seeds),
                               "failed_runs": int((~ok).sum())}  # fmt: skip
        for check in checks:
            row[f"check.{check.key}"] = check.verdict
            row[f"check.{check.key}.detail"] = check.detail
            within = (cells[f"check.{check.key}"] == PASS).mean() if len(cells) else math.nan
            row[f"seeds_passing.{check.key}"] = within
        row["passed"] = sum(row[f"check.{k}"] == PASS for k, _ in CHECKS)
        rows.append(row)
    return pd.DataFrame(rows)


def road_lines(roads: pd.DataFrame) -> list[str]:
    """The report's section of :func:`judged_by_road`: a row per road and share, each check's
    verdict on the seeds together with its values, and the share of seeds that passed it."""
    if roads.empty:
        return []
    shown = []
    for row in roads.to_dict("records"):
        cells = {"road": row["road"], "CAV share": share_name(row["share"]),
                 "seeds": row["seeds"]}  # fmt: skip
        for key, title in CHECKS:
            within = row[f"seeds_passing.{key}"]
            share_of = "-" if math.isnan(within) else f"{100 * within:.0f} %"
            cells[title] = f"{_mark(row[f'check.{key}'])} {row[f'check.{key}.detail']} ({share_of})"
        cells["passed"] = f"{row['passed']}/{len(CHECKS)}"
        cells["failed runs"] = row["failed_runs"]
        shown.append(cells)
    total = len(roads) * len(CHECKS)
    passed = int(roads["passed"].sum())
    return [
        "## Per road and share, the seeds together",
        "",
        "Each controller's measures over the seeds where all three ran (the swarm's own "
        "checks, collisions, CAV-CAV gap and aborted, over every seed it ran in): the mean "
        "(CAV speed, throughput, others' delay), the sum (collisions, TTC conflicts, "
        "manoeuvres started and aborted), the smallest CAV-CAV gap; the same checks on them, "
        "the better or worse baseline being the controller that is so over the seeds; then in "
        "brackets the share of the seeds whose own check passed. A swarm run that failed "
        "leaves its road and share unjudged (n/a).",
        "",
        pd.DataFrame(shown).to_markdown(index=False, disable_numparse=True),
        "",
        f"**Checks passed, per road and share: {passed} / {total}.**",
        "",
    ]


_MEASURE_KEYS = ("collisions", "cav_speed_mps", "throughput_vph", "others_delay_s", "ttc_events",
                 "cav_cav_gap_min_m", "started", "aborted", "cavs", "wall_s")  # fmt: skip


def _clean(value: Any) -> Any:
    """A value of a row read back (NaN for a missing one) as the checks take it (None)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return None
    return value


def _cell(value: Any, digits: int) -> str:
    value = _clean(value)
    return "-" if value is None else f"{float(value):.{digits}f}"


def _mark(verdict: str) -> str:
    return {PASS: "PASS", FAIL: "**FAIL**", NA: "n/a"}[verdict]


def failures(wide: pd.DataFrame) -> list[str]:
    """A line per check that did not pass: road, share, seed, check and its values."""
    out = []
    for row in wide.to_dict("records"):
        for key, title in CHECKS:
            if row[f"check.{key}"] != PASS:
                out.append(
                    f"{row['road']} at {share_name(row['share'])} (seed {row['seed']}): "
                    f"{title.split(' [')[0]}: {row[f'check.{key}']} ({row[f'check.{key}.detail']})"
                )
    return out


def report(
    wide: pd.DataFrame,
    shown: pd.DataFrame,
    command: str,
    commit: str,
    end_s: float,
    run_commits: Sequence[str] = (),
    roads: pd.DataFrame | None = None,
) -> str:
    """The Markdown report: what was run, the table, the checks passed and those that were
    not, then (``roads``, :func:`judged_by_road`) the checks of each road and share over its
    seeds; ``run_commits``: the commits the runs were made at (kept runs: earlier ones)."""
    total = len(wide) * len(CHECKS)
    passed = int(wide["passed"].sum()) if len(wide) else 0
    lines = [
        "# Corridor checks (issue 51): the swarm against sumo-cacc and sumo-lc",
        "",
        f"Commit `{commit}`{_made(run_commits, commit)}, `{command}`; {end_s:g} s simulated "
        f"per run at a step of {STEP_LENGTH_S:g} s for every controller. Each cell: "
        "PASS/FAIL, then swarm / sumo-cacc / sumo-lc (the aborted manoeuvres: the swarm's, of "
        "those it started). Roads: the OpenStreetMap motorways of sumo_swarm/sim/userroads.py "
        "(maps in networks/osm/, SUMO's default drivers, 15 % trucks, the CAVs drawn inside "
        "every flow) and the project's corridor (scenarios/corridor.toml cut to the run's "
        "length). Others' delay: the mean delay (timeLoss + insertion delay) of every vehicle "
        "that is not a CAV; CAV-CAV gap: the smallest bumper-to-bumper gap of a CAV behind a "
        "CAV.",
        "",
        shown.to_markdown(index=False, disable_numparse=True) if len(shown) else "No run.",
        "",
        f"**Checks passed: {passed} / {total}.**",
        "",
    ]
    missed = failures(wide)
    if missed:
        lines += ["Not passed:", "", *(f"- {m}" for m in missed), ""]
    if roads is not None:
        lines += road_lines(roads)
    return "\n".join(lines)


def _made(run_commits: Sequence[str], commit: str) -> str:
    others = [c for c in run_commits if c != commit]
    if not others:
        return ""
    return " (runs kept from " + ", ".join(f"`{c}`" for c in others) + ")"


def plan(
    roads: Sequence[str],
    shares: Sequence[float],
    seeds: Sequence[int],
    end_s: float,
    out: Path,
    commit: str = "",
) -> list[Job]:
    """Every run, its road's files written: road x share x seed x controller; ``commit``: this
    checkout's, recorded in the log of each run made."""
    jobs = []
    for road in roads:
        for share in shares:
            where = out / road / f"end-{end_s:g}"
            if STEP_LENGTH_S != DEFAULT_STEP_S:  # runs at another step apart
                where = where.with_name(f"{where.name}-step-{STEP_LENGTH_S:g}")
            args = road_args(road, share, end_s, where / "road")
            for seed in seeds:
                folder = where / f"share-{share_name(share)}" / f"seed-{seed}"
                jobs += [Job(road, share, seed, c, args, folder / c, commit) for c in CONTROLLERS]
    return jobs


def run_all(jobs: list[Job], *, workers: int, force: bool, timeout_s: float) -> pd.DataFrame:
    """Run ``jobs`` (``workers`` at once), a progress line each as it finishes; their rows in
    the order of ``jobs``."""
    done: dict[Job, dict[str, Any]] = {}
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        futures = {pool.submit(run_job, j, force=force, timeout_s=timeout_s): j for j in jobs}
        for future in as_completed(futures):
            job = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # a row with the error, never a lost table
                row = {"road": job.road, "share": job.share, "seed": job.seed}
                row.update(controller=job.controller, status="failed", error=repr(exc))
            done[job] = row
            what = row.get("error") or (
                f"CAV speed {_cell(row.get('cav_speed_mps'), 2)} m/s, collisions "
                f"{_cell(row.get('collisions'), 0)}, wall {_cell(row.get('wall_s'), 0)} s"
            )
            print(
                f"[{len(done)}/{len(jobs)}] {job.road} share {share_name(job.share)} seed "
                f"{job.seed} {job.controller}: {row['status']}, {what}",
                flush=True,
            )
    return pd.DataFrame([done[j] for j in jobs])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roads", nargs="+", choices=ROADS, default=list(ROADS))
    ap.add_argument("--shares", nargs="+", type=float, default=[0.2, 0.4], help="CAV shares")
    ap.add_argument("--end", type=float, default=300.0, help="simulated seconds per run")
    ap.add_argument("--step", type=float, default=DEFAULT_STEP_S, help="SUMO's step [s], all runs")
    ap.add_argument("--seeds", nargs="+", type=int, default=[42], help="SUMO's seeds")
    ap.add_argument("--out", type=Path, default=Path("/tmp/corridor_checks"), help="run folders")
    ap.add_argument("--workers", type=int, default=2, help="runs at once (one process each)")
    ap.add_argument("--force", action="store_true", help="run again runs that have a summary")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per run [s] of wall time")
    ap.add_argument(
        "--table",
        type=Path,
        default=ROOT / "docs" / "bench" / "corridor_checks",
        help="write TABLE.md and TABLE.csv (default docs/bench/corridor_checks)",
    )
    args = ap.parse_args(argv)
    bad = [s for s in args.shares if not 0.0 < s < 1.0 - 0.15]
    if bad:
        print(f"corridor_checks: --shares must be > 0 and < 0.85, got {bad}", file=sys.stderr)
        return 2
    global STEP_LENGTH_S
    STEP_LENGTH_S = args.step
    if args.end <= 0:
        print(f"corridor_checks: --end must be > 0, got {args.end:g}", file=sys.stderr)
        return 2
    commit = git_commit()
    jobs = plan(args.roads, args.shares, args.seeds, args.end, args.out, commit)
    runs = run_all(jobs, workers=args.workers, force=args.force, timeout_s=args.timeout)
    wide, shown = judged(runs)
    roads = judged_by_road(runs, wide)
    command = "python tools/corridor_checks.py " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    made = sorted(
        {c if isinstance(c, str) and c else "not recorded" for c in runs.get("run_commit", [])}
    )
    text = report(wide, shown, command.strip(), commit, args.end, made, roads)
    print(text)
    args.table.parent.mkdir(parents=True, exist_ok=True)
    table_file(args.table, ".md").write_text(text, encoding="utf-8")
    wide.insert(0, "commit", commit)
    wide.to_csv(table_file(args.table, ".csv"), index=False)
    roads.insert(0, "commit", commit)
    roads.to_csv(table_file(args.table, ".roads.csv"), index=False)
    runs.insert(0, "commit", commit)
    runs.to_csv(table_file(args.table, ".runs.csv"), index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
