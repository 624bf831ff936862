"""Where the runs of a batch execute: local worker processes, or a Ray cluster.

libsumo holds one simulation per process, so every run gets a process of its own, started for
that run and ended after it (memory stays flat however long the sweep). Both backends follow
:class:`Backend`; the batch loop is the same for both.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing as mp
import os
import signal
import threading
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any, Protocol

from tqdm import tqdm

from sumo_swarm.errors import ConfigError
from sumo_swarm.study.batch.store import execute_run, read_record
from sumo_swarm.study.batch.sweep import RunSpec

log = logging.getLogger(__name__)

PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class Outcome:
    """A submitted run that ended: its record, or why its worker left none."""

    spec: RunSpec
    record: dict[str, Any] | None
    error: str | None = None


class Backend(Protocol):
    """Runs :class:`RunSpec` s, at most ``capacity`` at a time."""

    capacity: int

    def submit(self, spec: RunSpec) -> None:
        """Start ``spec`` (the caller keeps at most ``capacity`` runs under way)."""

    def next_completed(self) -> Outcome:
        """Block until one submitted run ends; return it."""

    def close(self) -> None:
        """Stop what is still under way and release the workers."""


def available_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# --------------------------------------------------------------------------- local


def _die_with_parent(parent_pid: int) -> None:
    """Linux: get SIGKILL when the batch process dies, so no orphan keeps running."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before prctl
        os._exit(1)


def _local_worker(spec: RunSpec, batch_dir: str, parent_pid: int) -> None:
    _die_with_parent(parent_pid)
    # tqdm would create a multiprocessing lock (a named semaphore) that a run killed mid-way
    # (Ctrl-C, the batch ending) leaves behind; a thread lock is all one process needs.
    tqdm.set_lock(threading.RLock())
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    execute_run(spec, batch_dir)


def _exit_reason(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = " (out of memory?)" if -exitcode == signal.SIGKILL else ""
        return f"worker process killed by {name}{hint}"
    return f"worker process exited with status {exitcode}"


class LocalBackend:
    """One spawned process per run, ``workers`` at a time (spawn: nothing inherited)."""

    def __init__(self, batch_dir: Path, workers: int) -> None:
        if workers < 1:
            raise ConfigError(f"--workers must be at least 1, got {workers}")
        self.capacity = workers
        self.batch_dir = str(batch_dir)
        self._ctx = mp.get_context("spawn")
        self._running: dict[int, tuple[Any, RunSpec]] = {}

    def submit(self, spec: RunSpec) -> None:
        proc = self._ctx.Process(
            target=_local_worker, args=(spec, self.batch_dir, os.getpid()),
            name=f"sumo-swarm-run-{spec.run_id}", daemon=True,
        )  # fmt: skip
        proc.start()
        self._running[proc.sentinel] = (proc, spec)

    def next_completed(self) -> Outcome:
        if not self._running:
            raise RuntimeError("next_completed() with no run under way")
        sentinel = wait(list(self._running))[0]
        proc, spec = self._running.pop(sentinel)  # type: ignore[index]
        proc.join()
        folder = Path(self.batch_dir) / "runs" / spec.run_id
        if (folder / "done").is_file():
            return Outcome(spec, read_record(folder))
        return Outcome(spec, None, _exit_reason(proc.exitcode))

    def close(self) -> None:
        for proc, _ in self._running.values():
            proc.terminate()
        for proc, _ in self._running.values():
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
                proc.join()
        self._running.clear()


# --------------------------------------------------------------------------- ray


def _ray_task(spec: RunSpec, batch_dir: str) -> dict[str, Any]:
    return execute_run(spec, batch_dir)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "--ray needs Ray, which is not installed: pip install 'sumo-swarm[cluster]'"
        ) from None
    return ray


class RayBackend:
    """The runs as Ray tasks (one CPU each, a fresh worker process per task).

    ``address``: ``"auto"`` joins the cluster this machine belongs to, or starts a local Ray
    instance when there is none; anything else is passed to ``ray.init(address=...)`` (e.g.
    ``ray://head:10001``). An already initialised Ray (``ray.init`` called by the caller) is
    used as it is. Every node needs sumo-swarm installed; the run folders land in ``DIR`` on
    the node that ran them (use a shared file system to have them all in one place), while each
    run's record comes back to this process, so results.parquet is complete either way.
    """

    def __init__(self, batch_dir: Path, address: str, workers: int | None = None) -> None:
        ray = _import_ray()
        self._ray = ray
        self._owned = False
        if not ray.is_initialized():
            opts: dict[str, Any] = {"log_to_driver": False}
            if address == "auto":
                try:
                    ray.init(address="auto", **opts)
                except (ConnectionError, RuntimeError, ValueError):
                    log.info("no Ray cluster found: starting a local Ray instance")
                    if workers is not None:
                        opts["num_cpus"] = workers
                    ray.init(include_dashboard=False, **opts)
            else:
                try:
                    ray.init(address=address, **opts)
                except (ConnectionError, RuntimeError, ValueError) as exc:
                    msg = " ".join(str(exc).split())
                    raise ConfigError(f"--ray {address}: cannot connect: {msg}") from None
            self._owned = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.capacity = max(1, min(workers, cpus) if workers else cpus)
        self.batch_dir = str(batch_dir)
        self._task = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_ray_task)
        self._pending: dict[Any, RunSpec] = {}

    def submit(self, spec: RunSpec) -> None:
        self._pending[self._task.remote(spec, self.batch_dir)] = spec

    def next_completed(self) -> Outcome:
        if not self._pending:
            raise RuntimeError("next_completed() with no run under way")
        ready, _ = self._ray.wait(list(self._pending), num_returns=1)
        spec = self._pending.pop(ready[0])
        try:
            return Outcome(spec, self._ray.get(ready[0]))
        except Exception as exc:  # the worker died or Ray lost it
            return Outcome(spec, None, f"Ray task failed: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        for ref in self._pending:
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=True)
        self._pending.clear()
        if self._owned:
            self._ray.shutdown()


def make_backend(
    batch_dir: Path, *, workers: int | None = None, ray: str | None = None, runs: int = 0
) -> Backend:
    """The local pool (default: one worker per CPU, no more than ``runs``), or Ray."""
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if ray is not None:
        return RayBackend(batch_dir, ray, workers)
    n = workers or available_cpus()
    return LocalBackend(batch_dir, max(1, min(n, runs) if runs else n))
