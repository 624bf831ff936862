"""Batch sweeps: many runs of one base scenario, on this machine or on a Ray cluster.

``run_batch(sweep_file, out_dir)`` loads and validates the sweep (:mod:`.sweep`), skips the
runs already finished in ``out_dir``, runs the others one process each (:mod:`.backends`),
keeps every finished run in its own folder and rebuilds ``results.parquet`` after each one
(:mod:`.store`). Running it again resumes: nothing finished is redone or duplicated.
"""

from __future__ import annotations

import collections
import logging
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.runner import prepare_out_dir
from sumo_swarm.study.batch.backends import Backend, LocalBackend, RayBackend, make_backend
from sumo_swarm.study.batch.store import (
    RESULTS,
    STATUS_FAILED,
    BatchStore,
    check_batch_folder,
)
from sumo_swarm.study.batch.sweep import RunSpec, Sweep, find_case, load_sweep

log = logging.getLogger(__name__)

# Measures in the end-of-batch table: (results column, heading).
KEY_MEASURES = (
    ("cav.mean_speed_mps", "CAV speed [m/s]"),
    ("cav.travel_time_s", "travel time [s]"),
    ("overtake.all_past", "all past"),
    ("safety.collisions", "collisions"),
    ("safety.hard_brakes", "hard brakes"),
    ("upstream.first_follower_reduction_pct", "1st follower slowed [%]"),
)


# results.parquet is rebuilt after a finished run unless that would make rebuilding take more
# than this share of the batch process's time (large sweeps): then it waits for later runs. The
# run folders are the record; the table is rebuilt from them whenever a batch starts or ends.
RESULTS_WRITE_SHARE = 0.05


@dataclass
class BatchReport:
    """What a batch did: counts of this invocation and the results of the whole sweep."""

    out_dir: Path
    sweep: Sweep
    results: pd.DataFrame
    ran: int  # runs finished by this invocation (ok or failed)
    failed: int  # failed runs of the sweep (this invocation or before)
    skipped: int  # runs found finished and not run again
    elapsed_s: float

    @property
    def total(self) -> int:
        return len(self.sweep.runs)

    def table(self) -> str:
        """A short text table: counts, then the mean of key measures per controller."""
        from sumo_swarm.study.impact import markdown_table

        lines = [
            f"batch '{self.sweep.name}': {self.total} runs: {self.ran} run now, "
            f"{self.skipped} skipped (finished before), {self.failed} failed; "
            f"{self.elapsed_s:.0f} s -> {self.out_dir / RESULTS}"
        ]
        df = self.results
        if df.empty:
            return lines[0]
        rows = []
        for controller, group in df.groupby("controller", sort=False):
            ok = group[group["status"] == "ok"]
            row: dict[str, Any] = {
                "controller": controller,
                "runs": len(group),
                "failed": int((group["status"] == STATUS_FAILED).sum()),
            }
            for column, heading in KEY_MEASURES:
                if column in ok.columns and not ok.empty:
                    values = pd.to_numeric(ok[column], errors="coerce")
                    row[heading] = values.mean() if values.notna().any() else None
                else:
                    row[heading] = None
            rows.append(row)
        lines.append(markdown_table(pd.DataFrame(rows), digits=2))
        return "\n".join(lines)


def run_batch(
    sweep_file: str | Path,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    ray: str | None = None,
    retry_failed: bool = False,
    progress: bool | None = True,
    impact: bool = True,
) -> BatchReport:
    """Run every unfinished run of ``sweep_file`` into ``out_dir``; see the module docstring.

    ``workers``: runs at a time (default: one per CPU; with Ray, the cluster's CPUs).
    ``ray``: ``"auto"`` or a Ray address to run on Ray instead of local processes.
    ``retry_failed``: run the runs recorded as failed again (by default they count as finished).
    ``impact``: write the impact tables and plots (:func:`sumo_swarm.study.impact.impact`) at
    the end.
    Bad input (sweep file, folder, options) raises ConfigError before anything runs.
    """
    t0 = time.perf_counter()
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    sweep = load_sweep(sweep_file)
    check_batch_folder(Path(out_dir), sweep.path, {spec.run_id for spec in sweep.runs})
    out = prepare_out_dir(out_dir)
    store = BatchStore(out)
    with store.lock():
        removed = store.clean_staging()
        if removed:
            log.info("removed %d unfinished run folder(s) of an interrupted batch", removed)
        store.write_sweep(sweep)
        records: dict[str, dict[str, Any]] = {}
        pending: list[RunSpec] = []
        for spec in sweep.runs:
            record = store.finished(spec.run_id, spec)
            if record is not None and retry_failed and record["status"] == STATUS_FAILED:
                store.discard(spec.run_id)
                record = None
            if record is None:
                pending.append(spec)
            else:
                records[spec.run_id] = record
        skipped = len(records)
        results = store.write_results(sweep, records)
        if pending:
            pending.sort(key=lambda spec: -spec.cost)  # long runs first (stable otherwise)
            backend = make_backend(out, workers=workers, ray=ray, runs=len(pending))
            results = _run_all(sweep, store, backend, pending, records, progress)
    n_failed = int((results["status"] == STATUS_FAILED).sum()) if not results.empty else 0
    report = BatchReport(
        out, sweep, results, len(pending), n_failed, skipped, time.perf_counter() - t0
    )
    if impact and not results.empty:
        from sumo_swarm.study.impact import impact as write_impact

        write_impact(out)
    return report


def run_specs(
    backend: Backend,
    store: BatchStore,
    specs: Iterable[RunSpec],
    on_record: Callable[[dict[str, Any]], None],
) -> None:
    """Run ``specs`` in order on ``backend``, at most ``backend.capacity`` at a time.

    Each finished run's record (a failed one too: a worker that died leaves a failed record) is
    kept in ``store`` and handed to ``on_record`` as it comes. The backend is closed at the end,
    also when ``on_record`` raises or the caller is interrupted (the runs under way are stopped).
    """
    queue = collections.deque(specs)
    under_way = 0
    try:
        while queue or under_way:
            while queue and under_way < backend.capacity:
                backend.submit(queue.popleft())
                under_way += 1
            outcome = backend.next_completed()
            under_way -= 1
            if queue:  # start the next run before the bookkeeping, so no worker slot idles
                backend.submit(queue.popleft())
                under_way += 1
            record = outcome.record
            if record is None:
                record = store.fail(outcome.spec, outcome.error or "worker left no record")
            else:
                store.keep(record)
            on_record(record)
    finally:
        backend.close()


def _run_all(
    sweep: Sweep,
    store: BatchStore,
    backend: Backend,
    pending: list[RunSpec],
    records: dict[str, dict[str, Any]],
    progress: bool | None,
) -> pd.DataFrame:
    failed = 0
    next_write = 0.0  # results.parquet after every run, unless rebuilding it gets costly
    bar = tqdm(
        total=len(pending), desc=f"batch {sweep.name}", unit="run", file=sys.stderr,
        disable=(not progress) if progress is not None else None, dynamic_ncols=True,
    )  # fmt: skip

    def finished(record: dict[str, Any]) -> None:
        nonlocal failed, next_write
        records[record["run_id"]] = record
        if time.perf_counter() >= next_write:
            t_write = time.perf_counter()
            store.write_results(sweep, records)
            spent = time.perf_counter() - t_write
            next_write = t_write + spent * (1.0 + 1.0 / RESULTS_WRITE_SHARE)
        if record["status"] == STATUS_FAILED:
            failed += 1
            bar.set_postfix(failed=failed)
            tqdm.write(f"run {record['run_id']} failed: {record['error']}", file=sys.stderr)
        bar.update()

    try:
        run_specs(backend, store, pending, finished)
    finally:
        bar.close()
        for spec in pending:  # an interrupted batch: runs finished on disk, not yet told here
            if (
                spec.run_id not in records
                and (record := store.finished(spec.run_id, spec)) is not None
            ):
                records[spec.run_id] = record
        results = store.write_results(sweep, records)
    return results


__all__ = [
    "Backend",
    "BatchReport",
    "LocalBackend",
    "RayBackend",
    "RunSpec",
    "Sweep",
    "find_case",
    "load_sweep",
    "run_batch",
    "run_specs",
]
