"""One headless run: scenario + controller -> SUMO -> trajectories.parquet and summary.json."""

from __future__ import annotations

import logging
import os
import secrets
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from sumo_swarm.checks import SEED_MAX, require_number
from sumo_swarm.config import OutputSettings, Scenario
from sumo_swarm.controllers import make_controller
from sumo_swarm.controllers.base import Controller, RunContext, StandDown
from sumo_swarm.errors import ConfigError, RunInterrupted, SimulationError
from sumo_swarm.files import writable_folder
from sumo_swarm.sim.bridge import (
    SumoSession,
    is_of_type,
    sumo_binary,
    unknown_vtype,
    writes_parquet,
)
from sumo_swarm.sim.demand import (
    Demand,
    check_share_applies,
    read_demand,
    write_shared_demand,
)
from sumo_swarm.sim.fcd import FCD_FILE, fcd_args
from sumo_swarm.sim.gui import attach_plan_drawer
from sumo_swarm.sim.network import network_options
from sumo_swarm.sim.recorder import RunRecorder, records_every_row
from sumo_swarm.sim.runfolder import RunFolder, StopRequest, stop_on_signals
from sumo_swarm.sim.scene import (
    CAV_TYPE,
    LiveScene,
    default_settings,
    route_edges,
    write_sumo_inputs,
)
from sumo_swarm.sim.steplimit import check_step_length
from sumo_swarm.sim.sumoerrors import first_error, input_error, sumo_stderr
from sumo_swarm.userfiles import (
    MAX_DATA_BYTES,
    MAX_TEXT_BYTES,
    check_sumo_path,
    check_user_file,
    sumo_saved_path,
    xml_root_name,
)

log = logging.getLogger(__name__)


def prepare_out_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir`` (and parents) and check it is writable; ConfigError otherwise."""
    return writable_folder(out_dir)


def run_scenario(
    scenario: Scenario,
    controller_name: str,
    out_dir: str | Path,
    *,
    seed: int | None = None,
    fcd: bool = False,
    progress: bool | None = None,
    gui: bool = False,
    controller: Controller | None = None,
    force: bool = False,
    in_place: bool = False,
    stop: StopRequest | None = None,
) -> dict[str, Any]:
    """Run ``scenario`` under ``controller_name`` headless; write and return the summary.

    Outputs in ``out_dir``: ``summary.json``, ``trajectories.parquet``, ``events.jsonl``, the
    SUMO inputs under ``sumo/`` (``sumo/scenario.sumocfg`` holds every option and SUMO output
    of the run: ``sumo -c`` runs the same simulation, sumo-gui shows the scene),
    ``run.json`` (what the folder holds) and, with ``fcd``, SUMO's own ``fcd.xml``.
    ``controller`` replaces the named controller with an object of one's own (e.g. a swarm with
    another planner); ``controller_name`` still selects the CAVs' vehicle type.

    The outputs are written into a staging folder beside ``out_dir`` and moved into place at the
    end (:mod:`sumo_swarm.sim.runfolder`): ``out_dir`` must be new or empty, or hold an earlier
    run and ``force`` be given (the earlier run is then replaced). ``in_place``: write straight
    into ``out_dir`` (a folder the caller stages itself, as a batch does; no signal handling).
    SIGINT and SIGTERM (or ``stop``, set by the caller's own handlers) stop the run after the
    step under way: what was gathered is written, ``"complete": false``, and
    :class:`~sumo_swarm.errors.RunInterrupted` raised. A failure in SUMO or the controller is
    written the same way, then raised as SimulationError.
    """
    controller = controller or make_controller(controller_name)
    where = f"{scenario.path}: simulation.step_length_s" if scenario.path else "step_length_s"
    check_step_length(
        scenario.simulation.step_length_s, getattr(controller, "name", controller_name), where
    )
    check_sumo_path(Path(out_dir).resolve(), "output folder")
    if scenario.corridor is None:
        check_sumo_path(scenario.network_path, f"{scenario.path}: simulation.network")
    if seed is not None:
        scenario = replace(scenario, simulation=replace(scenario.simulation, seed=seed))

    def run(out: Path, stop: StopRequest) -> _Ending:
        net_args, net_files = _network_args(scenario, out / "sumo")
        recorded = _recorded_by_sumo(out, controller, scenario.outputs, fcd=fcd, gui=gui)
        # The configuration holds every option and output of the run (sumo -c runs the same
        # simulation with the same SUMO outputs: tools/bench_plumbing.py's yardstick).
        cfg, scene = write_sumo_inputs(
            scenario,
            controller_name,
            out / "sumo",
            [*net_args, *(fcd_args(recorded) if recorded else [])],
        )
        args = ["-c", str(cfg), *_fcd_args(out, fcd)]
        sim = scenario.simulation
        session = SumoSession(
            args,
            route_edges=route_edges(scenario),
            is_cav=lambda vid, type_id: is_of_type(type_id, CAV_TYPE),
            gui=gui,
            fcd_path=recorded,
        )
        if scene is None:  # a corridor: the CAVs are those SUMO inserts, as on a user's sumocfg
            scene = LiveScene(session, controller)
        return _drive(
            session,
            scenario,
            controller,
            controller_name,
            out,
            scene,
            max_steps=round(sim.duration_s / sim.step_length_s),
            progress=progress,
            network_files=net_files,
            stop=stop,
            user_files=_scenario_files(scenario, out / "sumo"),
        )

    return _in_run_folder(out_dir, run, force=force, in_place=in_place, stop=stop)


def _scenario_files(scenario: Scenario, folder: Path) -> UserFiles | None:
    """A scenario file, the network it names (a corridor builds its own) and the SUMO inputs
    written from it into ``folder``, for SUMO's errors about them; None for a scenario not
    read from a file."""
    if not scenario.path:
        return None
    network = [] if scenario.corridor is not None else [scenario.network_path]
    return scenario.path, network, sorted(folder.glob("*.xml"))


def run_sumocfg(
    sumocfg: str | Path,
    cav_type: str,
    controller_name: str,
    out_dir: str | Path,
    *,
    config: str | Path | None = None,
    seed: int | None = None,
    fcd: bool = False,
    progress: bool | None = None,
    gui: bool = False,
    max_duration_s: float = 3600.0,
    notify=print,
    force: bool = False,
    in_place: bool = False,
    stop: StopRequest | None = None,
    scale: float | None = None,
    cav_share: float | None = None,
    cav_share_of: str = "distribution",
    require_cavs: bool = True,
) -> dict[str, Any]:
    """Run a user's SUMO configuration as it is, the vehicles of vType ``cav_type`` forming the
    swarm. Options the swarm needs that the configuration lacks are added and reported in one
    line through ``notify``. Outputs, ``force``, ``in_place`` and ``stop`` as for
    :func:`run_scenario`. The run ends when SUMO has no vehicle left or at the configuration's
    end, and after ``max_duration_s`` at the latest.

    ``seed``: SUMO's ``--seed`` (default: the configuration's, else SUMO's own default); the
    summary's ``seed`` is the one SUMO ran with. ``scale``: SUMO's ``--scale`` (demand factor).
    ``cav_share``: the share of CAVs, of the ``vTypeDistribution`` s holding ``cav_type`` or of
    all passenger vehicles (``cav_share_of``), in copies of the demand files written into
    ``sumo/demand/`` of the run's folder (:mod:`sumo_swarm.sim.demand`). ``require_cavs``: a
    run in which no CAV departs is bad input (a wrong ``cav_type``); a study, whose draws may
    give none (share 0), says False.
    """
    cfg = Path(sumocfg)
    check_sumo_path(cfg.resolve(), "SUMO configuration")
    check_sumo_path(Path(out_dir).resolve(), "output folder")
    options = normalized_sumocfg_options(cfg)
    check_sumocfg_inputs(cfg, options)
    if scale is not None:
        require_number("scale", scale, gt=0.0)
    if cav_share is not None:
        require_number("cav_share", cav_share, ge=0.0, le=1.0)
    seed = sumocfg_seed(cfg, options) if seed is None else seed
    step = sumocfg_time_s(cfg, options, "step-length", 1.0)
    begin = sumocfg_time_s(cfg, options, "begin", 0.0)
    end = sumocfg_time_s(cfg, options, "end", max_duration_s)
    require_number(f"{cfg}: step-length", step, gt=0.0)
    default = "" if "step-length" in options else " (SUMO's default)"
    check_step_length(step, controller_name, f"{cfg}: step-length{default}")
    if end <= begin:
        raise ConfigError(f"{cfg}: end ({end:g} s) must be after begin ({begin:g} s)")
    end = min(end, max_duration_s)
    settings = default_settings(config)
    settings = replace(
        settings,
        name=cfg.stem,
        simulation=replace(settings.simulation, step_length_s=step, seed=seed),
        evaluation=replace(settings.evaluation, start_s=begin, end_s=end),
    )
    added = []
    if "lateral-resolution" not in options:
        added += ["--lateral-resolution", "0.5"]
    # Collisions are physical overlaps, counted and never teleported away (our safety measure).
    # The seed is always given, so the one in the summary is the one SUMO ran with.
    forced = ["--collision.mingap-factor", "0", "--collision.action", "warn"]
    forced += ["--seed", str(seed), "--random", "false"]
    if scale is not None:
        forced += ["--scale", f"{scale!r}"]
    demand = None
    if cav_share is not None:  # checked before the run's folder is made: bad input changes nothing
        demand = read_demand(demand_files(options))
        check_share_applies(demand, cav_type, cav_share_of, cfg)
    controller = make_controller(controller_name)

    def check_types(sess: SumoSession) -> None:
        message = unknown_vtype(cav_type, sess.api.vehicletype.getIDList())
        if message is not None:
            raise ConfigError(f"{cfg}: --cav-type: {message}")

    def run(out: Path, stop: StopRequest) -> _Ending:
        given, sumo_args = options, list(forced)
        if cav_share is not None:
            given, demand_args = _shared_demand(
                given, out / "sumo" / "demand", cav_type, cav_share, cav_share_of, demand
            )
            sumo_args += demand_args
        net_args, net_files = _network_args(settings, out / "sumo", given)
        if "--additional-files" in net_args and "--additional-files" in sumo_args:
            at = sumo_args.index("--additional-files")  # the network outputs' option lists them
            del sumo_args[at : at + 2]
        recorded = _recorded_by_sumo(
            out, controller, settings.outputs, fcd=fcd, gui=gui, given=given
        )
        args = ["-c", str(cfg.resolve()), *added, *sumo_args, "--no-step-log", "true", *net_args,
                *(fcd_args(recorded) if recorded else [])]  # fmt: skip
        # The record of what ran, in SUMO's own words: the user's inputs by absolute path and
        # every option, so sumo-gui -c sumo/scenario.sumocfg shows the same scene.
        save_sumo_configuration(cfg, args, out / "sumo" / "scenario.sumocfg")
        session = SumoSession(
            [*args, *_fcd_args(out, fcd)],
            is_cav=lambda vid, type_id: is_of_type(type_id, cav_type),
            gui=gui,
            fcd_path=recorded,
        )
        return _drive(
            session,
            settings,
            controller,
            controller_name,
            out,
            LiveScene(session, controller),
            max_steps=round((end - begin) / step),
            progress=progress,
            on_start=check_types,
            require_cavs=cav_type if require_cavs else None,
            network_files=net_files,
            stop=stop,
            user_files=_user_files(cfg, options),
        )

    summary = _in_run_folder(out_dir, run, force=force, in_place=in_place, stop=stop)
    if added:  # said once the run went through, so that bad input stays one line
        notify(f"sumo-swarm: {cfg}: added {' '.join(added)} (the swarm needs SUMO's sublane model)")
    return summary


# A user's configuration, the files of theirs SUMO reads, and those sumo-swarm wrote from it
UserFiles = tuple[Path, list[Path], list[Path]]


def _user_files(cfg: Path, options: dict[str, str]) -> UserFiles:
    """The configuration and the files SUMO reads of it (route and additional files before
    the network: SUMO's errors are more often about them)."""
    names = ("route-files", "additional-files", "net-file")
    files = [Path(p.strip()) for n in names for p in options.get(n, "").split(",") if p.strip()]
    return cfg, files, []


# SUMO's --seed when neither the command line nor the configuration gives one
# (``sumo --save-template``; tests/test_sumocfg_sweep.py checks it against SUMO).
SUMO_DEFAULT_SEED = 23423


def sumocfg_seed(cfg: Path, options: dict[str, str]) -> int:
    """The seed a configuration runs with: its own ``seed``, else SUMO's default. One that asks
    for a seed from the clock (``random``) gets one drawn here, so the run can be repeated."""
    if options.get("random", "false").lower() in ("true", "1", "yes", "on", "x"):
        return secrets.randbelow(SEED_MAX + 1)
    text = options.get("seed")
    if text is None:
        return SUMO_DEFAULT_SEED
    try:
        seed = int(text)
    except ValueError:
        raise ConfigError(f"{cfg}: seed: expected an integer, got {text!r}") from None
    require_number(f"{cfg}: seed", seed, ge=0, le=SEED_MAX, integer=True)
    return seed


def demand_files(options: dict[str, str]) -> list[Path]:
    """The files of a configuration that may hold vehicle types and vehicles, in the order SUMO
    loads them (additional files, then route files); paths as ``options`` give them."""
    return [
        Path(name.strip())
        for option in ("additional-files", "route-files")
        for name in options.get(option, "").split(",")
        if name.strip()
    ]


def _shared_demand(
    options: dict[str, str],
    folder: Path,
    cav_type: str,
    share: float,
    share_of: str,
    demand: Demand,
) -> tuple[dict[str, str], list[str]]:
    """The configuration's options with the CAV share applied (copies of the demand files that
    change, in ``folder``), and the SUMO options that load the copies; ``demand``: what the
    files hold (:func:`~sumo_swarm.sim.demand.read_demand`)."""
    copies = write_shared_demand(demand_files(options), folder, cav_type, share, share_of, demand)
    options = dict(options)
    args: list[str] = []
    for option in ("additional-files", "route-files"):
        names = [n.strip() for n in options.get(option, "").split(",") if n.strip()]
        if any(Path(n) in copies for n in names):
            options[option] = ",".join(str(copies.get(Path(n), Path(n))) for n in names)
            args += [f"--{option}", options[option]]
    return options, args


def read_sumocfg_options(path: Path) -> dict[str, str]:
    """The options of a SUMO configuration file (``{name: value}``); ConfigError if unusable."""
    from sumo_swarm.safexml import parse_xml

    root = parse_xml(path, what="SUMO configuration", max_bytes=MAX_TEXT_BYTES)
    options = {}
    for section in root:
        for opt in section:
            if "value" in opt.attrib:
                options[opt.tag] = opt.attrib["value"]
    return options


# Options of a SUMO configuration that name input files (comma-separated lists), relative to
# the configuration's folder.
SUMOCFG_INPUTS = ("net-file", "route-files", "additional-files", "weight-files", "load-state")
# Options that name files sumo-swarm reads or adds to: made absolute by
# normalized_sumocfg_options.
SUMOCFG_PATHS = (*SUMOCFG_INPUTS, "tripinfo-output", "device.ssm.file")


def normalized_sumocfg_options(cfg: Path) -> dict[str, str]:
    """The options of a SUMO configuration as SUMO itself reads them: by their full names
    (SUMO also accepts ``<additional>``, ``<tripinfo>``, ``<net>``, ...), the files of
    :data:`SUMOCFG_PATHS` by absolute path. SUMO writes the configuration out
    (``--save-configuration``); ConfigError if SUMO refuses it."""
    read_sumocfg_options(cfg)  # the file itself first, by our parser: missing, malformed, unsafe
    if "," in str(cfg.resolve().parent):
        # SUMO splits its file lists at commas, -c's and a folder's name included: it reads
        # the configuration, or the files beside it, as two missing ones.
        raise ConfigError(
            f"{cfg}: the folder's path holds a comma, which SUMO reads as the end of a file "
            "name in its file lists; move the configuration to a folder without one"
        )
    with tempfile.TemporaryDirectory() as tmp:
        saved = Path(tmp) / "user.sumocfg"
        save_sumo_configuration(cfg, ["-c", str(cfg.resolve())], saved)
        options = read_sumocfg_options(saved)
        for name in SUMOCFG_PATHS:
            if name in options:
                paths = [sumo_saved_path(p.strip()) for p in options[name].split(",") if p.strip()]
                options[name] = ",".join(os.path.abspath(Path(tmp) / p) for p in paths)
    return options


# What each input option of a configuration names, for messages
SUMO_INPUT_KIND = {
    "net-file": "a network",
    "route-files": "a route file",
    "additional-files": "an additional file",
    "weight-files": "a weight file",
    "load-state": "a saved state",
}


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_sumocfg_inputs(cfg: Path, options: dict[str, str]) -> None:
    """ConfigError naming the first input file of ``cfg`` that is missing, or no regular file
    of bounded size (SUMO's own message would be a "Process Error" with exit status 1; a FIFO
    would hang it)."""
    if not options.get("net-file"):
        raise ConfigError(f"{cfg}: no net-file in the SUMO configuration")
    for option in SUMOCFG_INPUTS:
        for name in options.get(option, "").split(","):
            if name.strip():
                path = cfg.parent / name.strip()
                try:
                    check_user_file(path, "file", MAX_DATA_BYTES)
                    check_sumo_path(path, "file")
                except ConfigError as exc:
                    raise ConfigError(f"{cfg}: {option}: {exc}") from None
                # A configuration where a network, routes or additionals belong (the file
                # itself, or another one): SUMO warns and reads nothing from it.
                root = xml_root_name(path)
                if root is not None and root.lower().endswith("configuration"):
                    which = "a SUMO configuration"
                    if _same_file(path, cfg):
                        which = "the configuration itself"
                    raise ConfigError(
                        f"{cfg}: {option}: {path} is {which}, not {SUMO_INPUT_KIND[option]}"
                    )


def sumocfg_time_s(cfg: Path, options: dict[str, str], name: str, default_s: float) -> float:
    """A time option of a SUMO configuration [s]: seconds or SUMO's ``[[[D:]H:]M:]S`` form;
    ConfigError naming the option and file unless it is a finite number."""
    text = options.get(name)
    if text is None:
        return default_s
    try:
        parts = [float(part) for part in text.split(":")]
    except ValueError:
        raise ConfigError(f"{cfg}: {name}: expected a time in seconds, got {text!r}") from None
    if len(parts) > 4:
        raise ConfigError(f"{cfg}: {name}: expected a time in seconds, got {text!r}")
    units = (1.0, 60.0, 3600.0, 86400.0)[: len(parts)]  # S, M:S, H:M:S, D:H:M:S
    seconds = sum(p * unit for p, unit in zip(reversed(parts), units, strict=True))
    require_number(f"{cfg}: {name}", seconds)
    return seconds


def save_sumo_configuration(cfg: Path, args: list[str], path: Path) -> None:
    """Have SUMO write the configuration ``args`` make to ``path``, without running it.

    SUMO refusing an option of the user's configuration is bad input: ConfigError with SUMO's
    message and the file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sumo_binary(), *args, "--save-configuration", str(path)]
    # A session of its own: Ctrl-C at the terminal stops the run, not this short call (its
    # failure would read as SUMO refusing the user's configuration).
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, start_new_session=True)
    if proc.returncode != 0:
        lines = [line.strip() for line in proc.stderr.splitlines() if line.strip()]
        reason = next((line for line in lines if line.startswith("Error")), None)
        reason = reason or (lines[0] if lines else f"exit status {proc.returncode}")
        raise ConfigError(f"{cfg}: SUMO refuses the configuration: {reason}")


def _network_args(
    scenario: Scenario, folder: Path, given: dict[str, str] | None = None
) -> tuple[list[str], dict[str, Path] | None]:
    """The SUMO options for the network measures (``[outputs] network``) and their files;
    ``given``: the user's options, paths absolute (:func:`normalized_sumocfg_options`)."""
    if not scenario.outputs.network:
        return [], None
    return network_options(folder, scenario.outputs, given)


def _recorded_by_sumo(
    out: Path,
    controller: Controller,
    outputs: OutputSettings,
    *,
    fcd: bool,
    gui: bool,
    given: Mapping[str, str] | None = None,
) -> Path | None:
    """Where SUMO writes the run's trajectories itself (:mod:`sumo_swarm.sim.fcd`): for a
    controller that reads no vehicle at any step (SUMO drives them all: ``reads_vehicles``
    False) in a run that records every vehicle at every step; else None (the session reads
    them). Not in sumo-gui (TraCI would read every lane at the start, and a window closed
    leaves the file unfinished), not with a libsumo that writes no Parquet (before 1.25), not
    when the run is asked for fcd.xml (``fcd``: SUMO writes one FCD output), nor when the
    user's configuration (``given``) has an FCD output of its
    own, sets up SUMO's FCD device (which vehicles and steps it writes) or prefixes its
    outputs."""
    if getattr(controller, "reads_vehicles", True) or not records_every_row(outputs):
        return None
    if fcd or gui or not writes_parquet():
        return None
    theirs = ("fcd-output", "device.fcd", "output-prefix")
    if given and any(name.startswith(theirs) for name in given):
        return None
    return (out / "sumo" / FCD_FILE).resolve()  # SUMO reads a relative one from the config's


def _fcd_args(out: Path, fcd: bool) -> list[str]:
    if not fcd:
        return []
    return ["--fcd-output", str(out / "fcd.xml"), "--fcd-output.acceleration", "true"]


def _start(session: SumoSession) -> None:
    """Start SUMO; SimulationError with SUMO's own first error when it refuses (libsumo says
    "Process Error" and SUMO prints the reason itself: held here, so bad input stays one
    line). What SUMO says at a start that succeeds (its warnings) is passed on as it is."""
    if session.use_traci:  # sumo-gui is a process of its own: its output stays its own
        session.start()
        return
    with sumo_stderr() as said:
        try:
            session.start()
        except SimulationError as exc:
            failure = exc
        else:
            failure = None
    if failure is None:
        sys.stderr.write(said[0])
        return
    reason = first_error(said[0])
    if reason is None or reason in str(failure):
        raise failure
    raise SimulationError(f"SUMO did not start: {reason}") from None


@dataclass
class _Ending:
    """How a run ended, told once its outputs are in place."""

    summary: dict[str, Any]
    failure: str | None = None  # SUMO or the controller failed mid-run
    cause: BaseException | None = None
    stopped: str | None = None  # why the run stopped early on a signal
    no_cavs: str | None = None  # the --cav-type whose vehicles never departed
    bad_input: ConfigError | None = None  # SUMO refused a user's file mid-run
    configuration: Path | None = None  # the user's file the run is of (a sumocfg, a scenario)


def _in_run_folder(
    out_dir: str | Path,
    run: Callable[[Path, StopRequest], _Ending],
    *,
    force: bool,
    in_place: bool,
    stop: StopRequest | None,
) -> dict[str, Any]:
    """``run(folder, stop)`` into a staging folder moved into ``out_dir`` at the end (or, with
    ``in_place``, into ``out_dir`` itself); then the run's summary, or how it ended raised.

    Staging is discarded when the run wrote no output (bad input, a stop before SUMO started),
    so ``out_dir`` stays as it was; once the outputs are being written, the folder is moved into
    place whatever happens, marked incomplete with the reason when the run did not finish."""
    if in_place:
        return _ended(run(prepare_out_dir(out_dir), stop or StopRequest()), Path(out_dir), stop)
    with stop_on_signals(stop) as stop:
        if stop.requested:
            raise stop.interrupted(f"interrupted by {stop.name}: nothing written to {out_dir}")
        folder = RunFolder(out_dir, force)
        try:
            ending = run(folder.staging, stop)
        except BaseException as exc:
            if (folder.staging / "events.jsonl").is_file():  # outputs half written: keep them
                folder.commit(f"the outputs could not all be written: {type(exc).__name__}: {exc}")
            else:
                folder.discard()
            if isinstance(exc, RunInterrupted):
                raise stop.interrupted(
                    f"interrupted by {stop.name} before SUMO ran: nothing written to {out_dir}"
                ) from None
            raise
        final = folder.commit(ending.summary.get("incomplete_reason"))
    return _ended(ending, final, stop)


def _ended(ending: _Ending, out: Path, stop: StopRequest | None) -> dict[str, Any]:
    """The summary of a run that ended as asked; otherwise how it ended, raised."""
    if ending.bad_input is not None:
        raise ending.bad_input
    if ending.failure is not None:
        raise SimulationError(f"{ending.failure} (outputs so far kept in {out})") from ending.cause
    if ending.stopped is not None and stop is not None:
        raise stop.interrupted(
            f"{ending.stopped}: the outputs gathered so far are in {out} "
            '(summary.json: "complete": false)'
        )
    if ending.no_cavs is not None:
        where = f"{ending.configuration}: " if ending.configuration is not None else ""
        raise ConfigError(
            f"{where}--cav-type: no vehicle of vType '{ending.no_cavs}' ever departed"
        )
    if stop is not None and stop.requested:  # the signal came while the outputs were written
        raise stop.interrupted(
            f"interrupted by {stop.name} after the last step: the run is complete in {out}"
        )
    return ending.summary


def _drive(
    session: SumoSession,
    scenario: Scenario,
    controller: Controller,
    controller_name: str,
    out: Path,
    scene,
    *,
    max_steps: int,
    progress: bool | None,
    on_start=None,
    require_cavs: str | None = None,
    network_files: dict[str, Path] | None = None,
    stop: StopRequest,
    user_files: UserFiles | None = None,
) -> _Ending:
    """Step SUMO, record, call the controller after every step, then write every output.

    Whatever happens during the run (a failure in SUMO or the controller, a ``stop`` request),
    the trajectories and events gathered so far are written and the summary is built from them,
    marked ``"complete": false`` with the reason; how the run ended is returned with it.
    ``user_files``: the user's configuration and the files it names; SUMO refusing them, at
    the start or over a vehicle, route or type of theirs later, is bad input naming the file.
    A controller's error stands the swarm down (:class:`StandDown`): the run goes on.
    """
    recorder = RunRecorder(
        session, controller, controller_name, scene, scenario.outputs, out_dir=out,
        count_conflicts=network_files is not None,
    )  # fmt: skip
    recorder.sumo_s = 0.0
    failure: str | None = None
    cause: BaseException | None = None
    stopped: str | None = None
    sumo_failed = False
    if stop.requested:  # before SUMO starts: nothing to keep
        raise stop.interrupted("interrupted before SUMO started")
    try:
        _start(session)
    except SimulationError as exc:
        if user_files is None:
            raise
        configuration, files, generated = user_files
        raise input_error(str(exc), files, configuration, generated=generated) from None
    with session:
        if on_start is not None:
            on_start(session)
        ctx = RunContext(session, scenario, session.cav_ids, session.first_road(), out_dir=out)
        guard = recorder.stand_down = StandDown(controller)  # a controller's error: once
        guard.attach(ctx)
        attach_plan_drawer(controller, ctx.session)
        bar = tqdm(
            total=max_steps,
            desc=f"{scenario.name}/{controller_name}",
            unit="step",
            disable=(not progress) if progress is not None else None,
            leave=False,
        )

        def stopped_now() -> str:
            why = f"interrupted by {stop.name} at t = {session.time_s:.2f} s"
            ctx.event("interrupted", signal=stop.name, message=why)
            return why

        try:
            for _ in range(max_steps):
                if stop.requested:  # checked between steps: the step's rows are whole
                    stopped = stopped_now()
                    break
                t0 = time.perf_counter()
                session.step()
                recorder.record()
                t1 = time.perf_counter()
                guard.control(session.time_s)
                recorder.controller_s += time.perf_counter() - t1
                recorder.sumo_s += t1 - t0
                bar.update()
                if not session.has_vehicles_to_come():
                    break
        except SimulationError as exc:
            if stop.requested:  # sumo-gui got the terminal's Ctrl-C too: a stop, not a failure
                stopped = stopped_now()
            else:
                failure, cause, sumo_failed = str(exc), exc, True
                ctx.event("sumo_failed", message=failure)
        except Exception as exc:  # a bug of ours: keep what was gathered, then report it
            # One line on the command line; the traceback with --verbose and in a batch run's
            # worker.log.
            log.info("run failed at t = %.2f s", session.time_s, exc_info=True)
            failure = f"{type(exc).__name__} at t = {session.time_s:.2f} s: {exc}"
            cause = exc
            ctx.event("run_failed", message=failure)
        finally:
            bar.close()
            recorder.close_controller()
    reason = failure or stopped
    summary = recorder.finish(
        out, scenario, ctx.events, network_files=network_files, incomplete_reason=reason
    )
    no_cavs = require_cavs if require_cavs is not None and not session.cav_ids else None
    bad = None
    if sumo_failed and user_files is not None:
        configuration, files, generated = user_files
        bad = input_error(failure or "", files, configuration, strict=True, generated=generated)
    where = user_files[0] if user_files is not None else None
    return _Ending(summary, failure, cause, stopped, no_cavs, bad, where)
