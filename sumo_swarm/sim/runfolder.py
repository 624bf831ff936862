"""A run's output folder, never half of one run nor two runs mixed, and stops on signals.

A run writes everything into a staging folder beside its ``--out`` folder,
``<out>.partial-<pid>``, and that folder is renamed into place at the end (a rename is atomic):
``--out`` holds the earlier run or this one, never a mix. ``run.json`` in the folder says what
it holds: ``state`` is ``running`` (a run under way, or one killed with SIGKILL: only its
staging folder is left), ``complete`` or ``incomplete`` (interrupted, or a failure in SUMO or
the controller: ``reason`` says which; the outputs are what was gathered until then).

A signal (SIGINT, SIGTERM, SIGHUP) during a run is a request to stop (:class:`StopRequest`): the run
stops after the step under way, writes what it gathered marked ``"complete": false`` and ends
with :class:`~sumo_swarm.errors.RunInterrupted`. A second signal while the outputs are written
changes nothing: the outputs are written whole first.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import sys
import threading
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sumo_swarm.errors import ConfigError, RunInterrupted, SimulationError
from sumo_swarm.files import folder_names, fsync_folder, shown_names, write_json_atomic

MANIFEST = "run.json"
MANIFEST_SCHEMA = "sumo-swarm/run-folder/1"
STATE_RUNNING, STATE_COMPLETE, STATE_INCOMPLETE = "running", "complete", "incomplete"
STAGING_INFIX = ".partial-"
# What a run leaves in its folder: a folder holding any of them holds a run (those written before
# run.json existed included).
RUN_MARKERS = (MANIFEST, "summary.json", "trajectories.parquet", "events.jsonl", "plans.jsonl",
               "sumo")  # fmt: skip


def _utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def holds_run(folder: Path) -> bool:
    """True if ``folder`` holds the outputs of a run (:data:`RUN_MARKERS`)."""
    return any((folder / name).exists() for name in RUN_MARKERS)


def check_out_folder(out: Path, force: bool) -> None:
    """ConfigError unless a run may be written to ``out``: a new or empty folder, or (with
    ``force``) one holding an earlier run, which the new run replaces as a whole. A folder
    holding anything else is never emptied, ``force`` or not."""
    names = folder_names(out, "output folder")
    if not names:
        return
    shown = shown_names(names)
    if not holds_run(out):
        raise ConfigError(
            f"output folder {out} holds files that are not a sumo-swarm run's ({shown}); "
            "give a new or empty folder"
        )
    if not force:
        raise ConfigError(
            f"output folder {out} holds an earlier run ({shown}); give another --out, or "
            "--force to replace it"
        )


class RunFolder:
    """The staging folder of one run and its move into ``out`` at the end.

    ``force``: ``out`` may hold an earlier run, replaced as a whole when this one is in place.
    ConfigError (before anything is written) if ``out`` cannot take the run.
    """

    def __init__(self, out: str | Path, force: bool = False) -> None:
        self.out = Path(out)
        self.force = force
        check_out_folder(self.out, force)
        # Symlinks and ".." resolved: the staging folder must sit beside the real folder, on the
        # same file system, for the rename to be atomic.
        target = Path(os.path.realpath(self.out))
        self._target = target
        name = f"{target.name}{STAGING_INFIX}{os.getpid()}"
        self.staging = target.parent / name
        if self.staging.exists():  # this process's own, of an earlier call
            self.staging = target.parent / f"{name}-{uuid.uuid4().hex[:6]}"
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            self.staging.mkdir()
        except OSError as exc:
            raise ConfigError(
                f"output folder {self.out} cannot be written: {exc.strerror or exc}"
            ) from None
        self.manifest: dict[str, Any] = {
            "schema": MANIFEST_SCHEMA,
            "state": STATE_RUNNING,
            "reason": None,
            "out": str(target),
            "command": list(sys.argv),
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "started_utc": _utc_now(),
            "finished_utc": None,
        }
        write_json_atomic(self.staging / MANIFEST, self.manifest)

    def commit(self, reason: str | None) -> Path:
        """Mark the run complete (``reason`` None) or incomplete (why), and move it into
        place; returns ``out``. If ``out`` was filled by someone else meanwhile, the run stays in
        its staging folder and SimulationError says where."""
        self.manifest.update(
            state=STATE_COMPLETE if reason is None else STATE_INCOMPLETE,
            reason=reason,
            finished_utc=_utc_now(),
            files=sorted(p.name for p in self.staging.iterdir() if p.name != MANIFEST),
        )
        write_json_atomic(self.staging / MANIFEST, self.manifest)
        target = self._target
        self._relocate(target)
        old = None
        if self.force and target.is_dir() and any(target.iterdir()):
            old = target.parent / f".{target.name}.replaced-{uuid.uuid4().hex[:8]}"
            os.rename(target, old)
        try:
            os.rename(self.staging, target)  # replaces an empty folder (POSIX)
        except OSError as exc:
            raise SimulationError(
                f"output folder {self.out} was filled by something else during the run "
                f"({exc.strerror or exc}); this run's outputs are in {self.staging}"
            ) from None
        fsync_folder(target.parent)  # the rename itself survives a crash
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.out

    def _relocate(self, target: Path) -> None:
        """Name ``target`` where the SUMO configuration written for the run names the staging
        folder (its outputs by absolute path), so ``sumo-gui -c sumo/scenario.sumocfg`` runs
        from the folder in place."""
        staged, final = str(self.staging), str(target)
        for path in [*self.staging.glob("sumo/*.sumocfg"), *self.staging.glob("sumo/*.add.xml")]:
            text = path.read_text(encoding="utf-8")
            if staged in text:
                path.write_text(text.replace(staged, final), encoding="utf-8")

    def discard(self) -> None:
        """Remove the staging folder (nothing worth keeping was written)."""
        shutil.rmtree(self.staging, ignore_errors=True)


class StopRequest:
    """A stop asked for by a signal, acted on where the run can stop cleanly (between steps)."""

    def __init__(self) -> None:
        self.signal: signal.Signals | None = None
        self.count = 0  # signals received

    @property
    def requested(self) -> bool:
        return self.signal is not None

    def request(self, signum: int) -> None:
        self.count += 1
        if self.signal is None:
            self.signal = signal.Signals(signum)

    @property
    def name(self) -> str:
        return self.signal.name if self.signal is not None else "an interrupt"

    @property
    def exit_status(self) -> int:
        """The shell's exit status for the signal: 128 + its number."""
        return 128 + int(self.signal or signal.SIGINT)

    def interrupted(self, message: str) -> RunInterrupted:
        return RunInterrupted(message, self.exit_status)


# Ctrl-C, kill's default, and the terminal closing (not on Windows).
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


@contextlib.contextmanager
def stop_on_signals(
    stop: StopRequest | None = None, signals: tuple[signal.Signals, ...] = STOP_SIGNALS
) -> Iterator[StopRequest]:
    """While inside, ``signals`` only set ``stop`` (a new one unless given); the handlers in
    place before are restored at the end. A signal ignored when entering (SIGHUP under nohup)
    stays ignored; outside the main thread (where Python cannot handle signals) nothing is
    installed."""
    stop = stop if stop is not None else StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {}
    try:
        for sig in signals:
            if signal.getsignal(sig) is signal.SIG_IGN:  # ignored on purpose (nohup, a & job)
                continue
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.request(signum))
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
