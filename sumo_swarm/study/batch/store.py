"""The batch folder: one folder per finished run, and the results tables rebuilt from them.

::

    DIR/sweep.json            the sweep as loaded: parameters, controllers, seeds, run ids
    DIR/results.parquet       one row per finished run of the sweep (rebuilt after every run)
    DIR/upstream.parquet      one row per upstream HV per run (the summaries' upstream lists)
    DIR/runs/<run_id>/        a finished run: record.json, done, and run_scenario's outputs
    DIR/runs/.<run_id>.<...>/ a run under way; renamed to runs/<run_id>/ once complete
    DIR/.lock                 held (flock) by the batch process while it runs

A run is finished when ``runs/<run_id>/done`` exists. A worker writes everything into its own
staging folder, ``record.json`` and then ``done`` last, and renames the folder into place: a
rename is atomic, so a batch killed at any moment (kill -9 included) leaves either a complete run
folder or none, and when two attempts of one run race, the first rename wins and the second
attempt is discarded. Staging folders left by a killed batch are removed when the next starts.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import re
import resource
import shutil
import socket
import sys
import time
import traceback
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from sumo_swarm.checks import finite_or_none
from sumo_swarm.errors import ConfigError
from sumo_swarm.files import (
    folder_names,
    shown_names,
    write_json_atomic,
    write_parquet_atomic,
)
from sumo_swarm.sim.metrics import INFLUENCE_THRESHOLD_PCT
from sumo_swarm.study.batch.sweep import RunSpec, Sweep

log = logging.getLogger(__name__)

RECORD_SCHEMA = "sumo-swarm/batch-run/1"
RUNS = "runs"
RECORD = "record.json"
DONE = "done"
RESULTS = "results.parquet"
UPSTREAM = "upstream.parquet"
SWEEP = "sweep.json"
LOCK = ".lock"
STATUS_OK, STATUS_FAILED = "ok", "failed"
ERROR_MAX_CHARS = 500
KEY_COLUMNS = ("controller", "seed", "run_id", "status", "error")


def one_line(exc: BaseException | str) -> str:
    """An error as one line: ``Type: message`` with whitespace collapsed, at most 500 chars."""
    text = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    text = " ".join(text.split())
    return text if len(text) <= ERROR_MAX_CHARS else text[: ERROR_MAX_CHARS - 3] + "..."


def peak_rss_mb() -> float:
    """Peak resident memory of this process [MB] (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cpu_s() -> float:
    """CPU time (user + system) of this process so far [s]."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@contextlib.contextmanager
def output_to(path: Path) -> Iterator[None]:
    """Send this process's stdout and stderr (file descriptors, so SUMO's too) to ``path``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    try:
        with path.open("ab") as fh:
            os.dup2(fh.fileno(), 1)
            os.dup2(fh.fileno(), 2)
            try:
                yield
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        os.close(saved[0])
        os.close(saved[1])


# --------------------------------------------------------------------------- worker side


def _record(spec: RunSpec, status: str, error: str | None, summary: Any, run: dict) -> dict:
    return {
        "schema": RECORD_SCHEMA,
        "run_id": spec.run_id,
        "status": status,
        "error": error,
        "controller": spec.controller,
        "seed": spec.seed,
        "params": spec.params,
        "base": spec.base_path,
        "overrides": spec.overrides,
        "summary": summary,
        "run": run,
    }


def execute_run(spec: RunSpec, batch_dir: str | Path) -> dict[str, Any]:
    """Run ``spec`` into ``batch_dir/runs/<run_id>/`` and return its record (worker side).

    Never raises for a failed run: the record says ``status = "failed"`` with the error in one
    line (the traceback is in the run folder's ``worker.log``). Interrupts (KeyboardInterrupt,
    SystemExit) leave no record, so the run is pending again.
    """
    runs = Path(batch_dir) / RUNS
    final = runs / spec.run_id
    if (final / DONE).is_file():
        return read_record(final)
    staging = runs / f".{spec.run_id}.{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
    staging.mkdir(parents=True)
    t0 = time.perf_counter()
    status, error, summary = STATUS_OK, None, None
    with output_to(staging / "worker.log"):
        try:
            summary = spec.run(staging)
        except Exception as exc:
            traceback.print_exc()
            status = STATUS_FAILED
            error = one_line(exc).replace(str(staging), str(final))
            partial = staging / "summary.json"  # a SUMO failure keeps the summary so far
            if partial.is_file():
                with contextlib.suppress(ValueError, OSError):
                    summary = json.loads(partial.read_text(encoding="utf-8"))
    if error is not None:
        error = one_line(f"{error}{_sumo_error(staging / 'worker.log', error)}")
    run = {
        "elapsed_s": time.perf_counter() - t0,
        "cpu_s": cpu_s(),  # the worker process's, start-up (imports) included
        "peak_rss_mb": peak_rss_mb(),
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "finished_at": time.time(),
    }
    record = _record(spec, status, error, summary, run)
    write_json_atomic(staging / RECORD, record)
    (staging / DONE).write_text("", encoding="utf-8")
    if not commit(staging, final):
        return read_record(final)
    return record


def _sumo_error(log_file: Path, error: str) -> str:
    """SUMO's first ``Error:`` line of the run's log, as a suffix for ``error`` (libsumo's
    exception often says only "Process Error"); empty if none or already in ``error``."""
    try:
        text = log_file.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""
    found = re.search(r"^Error: (.+)$", text, re.MULTILINE)
    if found is None or found.group(1).strip() in error:
        return ""
    return f" (SUMO: {found.group(1).strip()})"


def commit(staging: Path, final: Path) -> bool:
    """Rename a complete staging folder into place; False if another attempt got there first."""
    try:
        os.rename(staging, final)
        return True
    except OSError:
        if (final / DONE).is_file():
            shutil.rmtree(staging, ignore_errors=True)
            return False
        if not final.exists():
            raise
    # A folder without `done` is not a run (it cannot come from a rename): replace it.
    _discard(final)
    os.rename(staging, final)
    return True


def read_record(folder: Path) -> dict[str, Any]:
    return json.loads((folder / RECORD).read_text(encoding="utf-8"))


def record_problem(record: Any, run_id: str, spec: RunSpec | None = None) -> str | None:
    """Why ``record`` is not a well-formed record of run ``run_id`` (of ``spec``, if given:
    its controller and seed too); None if it is one."""
    if not isinstance(record, dict):
        return f"not a record (a JSON {type(record).__name__}, not an object)"
    if record.get("schema") != RECORD_SCHEMA:
        return f"not a record (schema {record.get('schema')!r}, not {RECORD_SCHEMA!r})"
    own = {"run_id": run_id}
    if spec is not None:
        own.update(controller=spec.controller, seed=spec.seed)
    for key, value in own.items():
        if record.get(key) != value:
            return f"another run's record ({key} {record.get(key)!r}, this run's {value!r})"
    status, summary = record.get("status"), record.get("summary")
    if status not in (STATUS_OK, STATUS_FAILED):
        return f"status {status!r} is neither {STATUS_OK!r} nor {STATUS_FAILED!r}"
    if not isinstance(record.get("error"), str | None):
        return "error is not a text"
    for key in ("params", "run"):
        if not isinstance(record.get(key), dict | None):
            return f"{key} is not a JSON object"
    if summary is None:
        return "status 'ok' without a summary" if status == STATUS_OK else None
    if not isinstance(summary, dict) or not str(summary.get("schema")).startswith(
        "sumo-swarm/summary/"
    ):
        return "its summary is not a sumo-swarm summary"
    if summary.get("controller") != record["controller"]:
        return f"its summary is of controller {summary.get('controller')!r}, not the run's"
    return None


def _discard(folder: Path) -> None:
    """Remove a folder: renamed out of the way first, so a crash never leaves half of it."""
    trash = folder.parent / f".{folder.name}.trash.{uuid.uuid4().hex[:8]}"
    os.rename(folder, trash)
    shutil.rmtree(trash, ignore_errors=True)


# --------------------------------------------------------------------------- driver side


# What a batch leaves in its folder: a folder holding any of them holds a batch
BATCH_MARKERS = (SWEEP, RUNS, RESULTS, UPSTREAM, LOCK)


def check_batch_folder(out: Path, sweep_file: Path, run_ids: set[str]) -> None:
    """ConfigError unless ``out`` may take the batch of sweep ``sweep_file`` (its runs
    ``run_ids``): new, empty, or the folder of this sweep (resumed). Never a folder of other
    files (``--out /``, a project folder), nor another sweep's batch: its runs would sit
    beside this one's, and its sweep.json would be overwritten."""
    names = folder_names(out, "batch folder")
    if not names:
        return
    if not any(name in names for name in BATCH_MARKERS):
        raise ConfigError(
            f"batch folder {out} holds files that are not a sumo-swarm batch's "
            f"({shown_names(names)}); "
            "give a new or empty folder"
        )
    try:
        stored = json.loads((out / SWEEP).read_text(encoding="utf-8"))
        stored_file, stored_runs = stored["sweep_file"], set(stored["runs"])
    except (OSError, ValueError, KeyError, TypeError):
        return  # no readable sweep.json: the records themselves are checked run by run
    # The same sweep file (grown or changed: its runs in common are kept), or one sharing runs
    if Path(str(stored_file)) != sweep_file and not (stored_runs & run_ids):
        raise ConfigError(
            f"batch folder {out} holds the batch of another sweep ({stored_file}); give "
            "another --out"
        )


class BatchStore:
    """The batch folder ``out`` as seen by the batch process."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.runs = out / RUNS
        # The batch's own names taken by something of the wrong kind (a folder where a table
        # belongs): every later write or rename onto them would fail mid-batch.
        for name, is_folder in ((RUNS, True), (RESULTS, False), (UPSTREAM, False), (SWEEP, False)):
            path = out / name
            if (path.exists() or path.is_symlink()) and path.is_dir() != is_folder:
                found = "a folder" if path.is_dir() else "not a folder"
                wanted = "the folder of the runs" if is_folder else "a file of the batch"
                raise ConfigError(f"{path}: {found}, where {wanted} belongs; move it away")
        self.runs.mkdir(parents=True, exist_ok=True)

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold ``DIR/.lock`` while the batch runs: one batch per folder at a time."""
        with (self.out / LOCK).open("a+") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise ConfigError(f"{self.out}: another batch is running in this folder") from None
            fh.seek(0)
            fh.truncate()
            fh.write(f"{socket.gethostname()} {os.getpid()}\n")
            fh.flush()
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def clean_staging(self) -> int:
        """Remove what killed attempts left (call with the lock held); returns how many."""
        left = [p for p in self.runs.iterdir() if p.name.startswith(".") and p.is_dir()]
        for p in left:
            shutil.rmtree(p, ignore_errors=True)
        return len(left)

    def write_sweep(self, sweep: Sweep) -> None:
        write_json_atomic(self.out / SWEEP, sweep.to_json())

    def finished(self, run_id: str, spec: RunSpec | None = None) -> dict[str, Any] | None:
        """The record of a finished run, None if it has not finished.

        A record that cannot be read, is not well formed or is another run's (``spec``, when
        given, says whose it must be) is discarded with a warning naming the file: the run is
        redone, never listed under another run's name or as an empty row."""
        folder = self.runs / run_id
        if not (folder / DONE).is_file():
            return None
        try:
            record = read_record(folder)
        except (OSError, ValueError) as exc:
            problem = f"unreadable ({type(exc).__name__}: {' '.join(str(exc).split())})"
        else:
            problem = record_problem(record, run_id, spec)
            if problem is None:
                return record
        log.warning("%s: %s; the run will be redone", folder / RECORD, problem)
        _discard(folder)
        return None

    def discard(self, run_id: str) -> None:
        folder = self.runs / run_id
        if folder.exists():
            _discard(folder)

    def keep(self, record: dict[str, Any]) -> None:
        """Make sure a record returned by a worker is on this machine's disk.

        A remote worker (Ray on a cluster without a shared file system) wrote its run folder
        on its own node; the batch keeps the record here, so the results are complete.
        """
        final = self.runs / record["run_id"]
        if (final / DONE).is_file():
            return
        staging = self.runs / f".{record['run_id']}.record.{uuid.uuid4().hex[:8]}"
        staging.mkdir()
        write_json_atomic(staging / RECORD, record)
        (staging / DONE).write_text("", encoding="utf-8")
        commit(staging, final)

    def fail(self, spec: RunSpec, error: str) -> dict[str, Any]:
        """Record a run whose worker died without a record (crash, out of memory, lost node)."""
        run = {
            "elapsed_s": None,
            "cpu_s": None,
            "peak_rss_mb": None,
            "host": None,
            "pid": None,
            "finished_at": time.time(),
        }
        record = _record(spec, STATUS_FAILED, one_line(error), None, run)
        self.keep(record)
        return self.finished(spec.run_id, spec) or record

    def write_results(self, sweep: Sweep, records: Mapping[str, dict[str, Any]]) -> pd.DataFrame:
        """Rebuild results.parquet and upstream.parquet (tmp file + rename) from ``records``."""
        finished = [records[r.run_id] for r in sweep.runs if r.run_id in records]
        frame = results_frame(finished, sweep.parameters)
        write_parquet_atomic(self.out / RESULTS, frame)
        write_parquet_atomic(self.out / UPSTREAM, upstream_frame(finished, sweep.parameters))
        return frame


# --------------------------------------------------------------------------- flat rows


def _cell(value: Any) -> Any:
    """A value for a table cell: lists and tables as JSON text, non-finite floats as None."""
    if isinstance(value, list | dict):
        return json.dumps(value, sort_keys=True)
    if isinstance(value, float):
        return finite_or_none(value)
    return value


def flatten(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, Mapping):
            out.update(flatten(value, dotted))
        else:
            out[dotted] = _cell(value)
    return out


def upstream_measures(upstream: list[dict[str, Any]] | None) -> dict[str, Any]:
    """The summary's upstream list as a few numbers (the list is in upstream.parquet).

    ``hv_count``: upstream HVs measured; ``hv_influenced``: those slowed by more than
    :data:`INFLUENCE_THRESHOLD_PCT`; ``first_follower_reduction_pct``: the largest speed
    reduction of the HVs right behind the swarm (rank 1, any lane); ``max_reduction_pct``,
    ``mean_reduction_pct`` over all; ``min_gap_m``, ``min_headway_s``: the smallest over all.
    """
    rows = upstream or []

    def values(key: str, rank: int | None = None) -> list[float]:
        return [
            float(r[key])
            for r in rows
            if r.get(key) is not None and (rank is None or r.get("rank") == rank)
        ]

    red = values("speed_reduction_pct")
    first = values("speed_reduction_pct", rank=1)
    gaps = values("min_gap_m")
    headways = values("min_headway_s")
    return {
        "upstream.hv_count": len(rows),
        "upstream.hv_influenced": sum(x > INFLUENCE_THRESHOLD_PCT for x in red),
        "upstream.first_follower_reduction_pct": max(first) if first else None,
        "upstream.max_reduction_pct": max(red) if red else None,
        "upstream.mean_reduction_pct": sum(red) / len(red) if red else None,
        "upstream.min_gap_m": min(gaps) if gaps else None,
        "upstream.min_headway_s": min(headways) if headways else None,
    }


def flat_row(record: Mapping[str, Any]) -> dict[str, Any]:
    """One results row: parameters, key columns, run.*, and the summary flattened with dots.

    Parameters win over summary fields of the same name (``cav.count``: the same value).
    """
    row: dict[str, Any] = {k: _cell(v) for k, v in record.get("params", {}).items()}
    row.update({k: record.get(k) for k in KEY_COLUMNS})
    row.update(flatten(record.get("run") or {}, "run"))
    summary = dict(record.get("summary") or {})
    summary.pop("schema", None)
    upstream = summary.pop("upstream", None)
    for key, value in [*flatten(summary).items(), *upstream_measures(upstream).items()]:
        row.setdefault(key, value)
    return row


def results_frame(records: list[Mapping[str, Any]], parameters: tuple[str, ...]) -> pd.DataFrame:
    rows = [flat_row(r) for r in records]
    columns = list(dict.fromkeys([*parameters, *KEY_COLUMNS]))
    for row in rows:
        columns.extend(k for k in row if k not in columns)
    df = pd.DataFrame.from_records(rows, columns=columns)
    # A table that is None in some summaries (planner.statuses of a baseline) and has keys in
    # others: keep the keys' columns only.
    parents = [
        c
        for c in df.columns
        if df[c].isna().all() and any(o.startswith(f"{c}.") for o in df.columns)
    ]
    df = df.drop(columns=parents)
    statuses = [c for c in df.columns if c.startswith("planner.statuses.")]
    if statuses and "planner.solves" in df.columns:
        planned = df["planner.solves"].notna()
        df.loc[planned, statuses] = df.loc[planned, statuses].fillna(0)
    return df


def upstream_frame(records: list[Mapping[str, Any]], parameters: tuple[str, ...]) -> pd.DataFrame:
    rows = []
    for record in records:
        keys = {k: _cell(v) for k, v in record.get("params", {}).items()}
        keys.update(controller=record["controller"], seed=record["seed"], run_id=record["run_id"])
        for hv in (record.get("summary") or {}).get("upstream") or []:
            rows.append({**keys, **hv})
    columns = [*parameters, "controller", "seed", "run_id", "lane", "rank", "vehicle"]
    df = pd.DataFrame.from_records(rows)
    if df.empty:
        return pd.DataFrame(columns=columns)
    return df[[*[c for c in columns if c in df.columns], *[c for c in df if c not in columns]]]
