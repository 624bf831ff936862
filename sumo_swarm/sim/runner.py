"""One headless run: scenario + controller -> SUMO -> trajectories.parquet and summary.json."""

from __future__ import annotations

import logging
import os
import subprocess
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from sumo_swarm.checks import require_number
from sumo_swarm.config import Scenario
from sumo_swarm.controllers import make_controller
from sumo_swarm.controllers.base import Controller, RunContext
from sumo_swarm.errors import ConfigError, SimulationError
from sumo_swarm.sim.bridge import SumoSession, is_of_type, sumo_binary
from sumo_swarm.sim.gui import attach_plan_drawer
from sumo_swarm.sim.network import network_options
from sumo_swarm.sim.recorder import RunRecorder
from sumo_swarm.sim.scene import (
    CAV_TYPE,
    LiveScene,
    default_settings,
    route_edges,
    sumo_options,
    write_sumo_inputs,
)
from sumo_swarm.sim.steplimit import check_step_length

log = logging.getLogger(__name__)


def prepare_out_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir`` (and parents) and check it is writable; ConfigError otherwise."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("", encoding="utf-8")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"output folder {out} cannot be written: {exc.strerror or exc}") from None
    return out


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
) -> dict[str, Any]:
    """Run ``scenario`` under ``controller_name`` headless; write and return the summary.

    Outputs in ``out_dir``: ``summary.json``, ``trajectories.parquet``, ``events.jsonl``, the
    SUMO inputs under ``sumo/`` (open ``sumo/scenario.sumocfg`` in sumo-gui to watch the scene)
    and, with ``fcd``, SUMO's own ``fcd.xml``. ``controller`` replaces the named controller
    with an object of one's own (e.g. a swarm with another planner); ``controller_name`` still
    selects the CAVs' vehicle type.
    """
    controller = controller or make_controller(controller_name)
    where = f"{scenario.path}: simulation.step_length_s" if scenario.path else "step_length_s"
    check_step_length(
        scenario.simulation.step_length_s, getattr(controller, "name", controller_name), where
    )
    out = prepare_out_dir(out_dir)
    if seed is not None:
        scenario = replace(scenario, simulation=replace(scenario.simulation, seed=seed))
    cfg, scene = write_sumo_inputs(scenario, controller_name, out / "sumo")
    net_args, net_files = _network_args(scenario, out / "sumo")
    args = ["-c", str(cfg), *sumo_options(scenario), *_fcd_args(out, fcd), *net_args]
    sim = scenario.simulation
    session = SumoSession(
        args,
        route_edges=route_edges(scenario),
        is_cav=lambda vid, type_id: is_of_type(type_id, CAV_TYPE),
        gui=gui,
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
    )


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
) -> dict[str, Any]:
    """Run a user's SUMO configuration as it is, the vehicles of vType ``cav_type`` forming the
    swarm. Options the swarm needs that the configuration lacks are added and reported in one
    line through ``notify``. Outputs as for :func:`run_scenario`. The run ends when SUMO has no
    vehicle left or at the configuration's end, and after ``max_duration_s`` at the latest.
    """
    cfg = Path(sumocfg)
    options = normalized_sumocfg_options(cfg)
    check_sumocfg_inputs(cfg, options)
    step = sumocfg_time_s(cfg, options, "step-length", 1.0)
    begin = sumocfg_time_s(cfg, options, "begin", 0.0)
    end = sumocfg_time_s(cfg, options, "end", max_duration_s)
    require_number(f"{cfg}: step-length", step, gt=0.0)
    default = "" if "step-length" in options else " (SUMO's default)"
    check_step_length(step, controller_name, f"{cfg}: step-length{default}")
    if end <= begin:
        raise ConfigError(f"{cfg}: end ({end:g} s) must be after begin ({begin:g} s)")
    end = min(end, max_duration_s)
    out = prepare_out_dir(out_dir)
    settings = default_settings(config)
    settings = replace(
        settings,
        name=cfg.stem,
        simulation=replace(settings.simulation, step_length_s=step),
        evaluation=replace(settings.evaluation, start_s=begin, end_s=end),
    )
    added = []
    if "lateral-resolution" not in options:
        added += ["--lateral-resolution", "0.5"]
    # Collisions are physical overlaps, counted and never teleported away (our safety measure).
    forced = ["--collision.mingap-factor", "0", "--collision.action", "warn"]
    if seed is not None:
        forced += ["--seed", str(seed)]
    net_args, net_files = _network_args(settings, out / "sumo", options)
    args = ["-c", str(cfg.resolve()), *added, *forced, "--no-step-log", "true", *net_args]
    # The record of what ran, in SUMO's own words: the user's inputs by absolute path and every
    # option, so sumo-gui -c sumo/scenario.sumocfg shows the same scene.
    save_sumo_configuration(cfg, args, out / "sumo" / "scenario.sumocfg")
    controller = make_controller(controller_name)
    session = SumoSession(
        [*args, *_fcd_args(out, fcd)],
        is_cav=lambda vid, type_id: is_of_type(type_id, cav_type),
        gui=gui,
    )

    def check_types(sess: SumoSession) -> None:
        if cav_type not in sess.api.vehicletype.getIDList():
            raise ConfigError(f"{cfg}: --cav-type: no vType '{cav_type}' in the configuration")
        if added:  # reported once SUMO has accepted the run, so bad input stays one line
            notify(
                f"sumo-swarm: {cfg}: added {' '.join(added)} (the swarm needs SUMO's sublane model)"
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
        require_cavs=cav_type,
        network_files=net_files,
    )


def read_sumocfg_options(path: Path) -> dict[str, str]:
    """The options of a SUMO configuration file (``{name: value}``); ConfigError if unusable."""
    from sumo_swarm.safexml import parse_xml

    root = parse_xml(path, what="SUMO configuration")
    options = {}
    for section in root:
        for opt in section:
            if "value" in opt.attrib:
                options[opt.tag] = opt.attrib["value"]
    return options


# Options of a SUMO configuration that name input files (comma-separated lists), relative to
# the configuration's folder.
SUMOCFG_INPUTS = ("net-file", "route-files", "additional-files")
# Options that name files sumo-swarm reads or adds to: made absolute by
# normalized_sumocfg_options.
SUMOCFG_PATHS = (*SUMOCFG_INPUTS, "tripinfo-output", "device.ssm.file")


def normalized_sumocfg_options(cfg: Path) -> dict[str, str]:
    """The options of a SUMO configuration as SUMO itself reads them: by their full names
    (SUMO also accepts ``<additional>``, ``<tripinfo>``, ``<net>``, ...), the files of
    :data:`SUMOCFG_PATHS` by absolute path. SUMO writes the configuration out
    (``--save-configuration``); ConfigError if SUMO refuses it."""
    read_sumocfg_options(cfg)  # the file itself first, by our parser: missing, malformed, unsafe
    with tempfile.TemporaryDirectory() as tmp:
        saved = Path(tmp) / "user.sumocfg"
        save_sumo_configuration(cfg, ["-c", str(cfg.resolve())], saved)
        options = read_sumocfg_options(saved)
        for name in SUMOCFG_PATHS:
            if name in options:
                paths = [p.strip() for p in options[name].split(",") if p.strip()]
                options[name] = ",".join(os.path.abspath(Path(tmp) / p) for p in paths)
    return options


def check_sumocfg_inputs(cfg: Path, options: dict[str, str]) -> None:
    """ConfigError naming the first input file of ``cfg`` that is missing (SUMO's own message
    would be a "Process Error" with exit status 1)."""
    if not options.get("net-file"):
        raise ConfigError(f"{cfg}: no net-file in the SUMO configuration")
    for option in SUMOCFG_INPUTS:
        for name in options.get(option, "").split(","):
            path = cfg.parent / name.strip()
            if name.strip() and not path.is_file():
                raise ConfigError(f"{cfg}: {option}: file not found: {path}")


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
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
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


def _fcd_args(out: Path, fcd: bool) -> list[str]:
    if not fcd:
        return []
    return ["--fcd-output", str(out / "fcd.xml"), "--fcd-output.acceleration", "true"]


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
) -> dict[str, Any]:
    """Step SUMO, record, call the controller after every step, then write every output.

    Whatever happens during the run, the trajectories and events gathered so far are written
    and the summary is built from them; a SUMO failure is raised after that.
    """
    recorder = RunRecorder(
        session, controller, controller_name, scene, scenario.outputs, out_dir=out
    )
    recorder.sumo_s = 0.0
    failure: str | None = None
    with session:
        if on_start is not None:
            on_start(session)
        ctx = RunContext(session, scenario, session.cav_ids, session.first_road(), out_dir=out)
        controller.attach(ctx)
        attach_plan_drawer(controller, ctx.session)
        bar = tqdm(
            total=max_steps,
            desc=f"{scenario.name}/{controller_name}",
            unit="step",
            disable=(not progress) if progress is not None else None,
            leave=False,
        )
        try:
            for _ in range(max_steps):
                t0 = time.perf_counter()
                session.step()
                recorder.record()
                t1 = time.perf_counter()
                controller.control(session.time_s)
                recorder.controller_s += time.perf_counter() - t1
                recorder.sumo_s += t1 - t0
                bar.update()
                if not session.has_vehicles_to_come():
                    break
        except SimulationError as exc:
            failure = str(exc)
            ctx.event("sumo_failed", message=failure)
        except Exception as exc:  # a controller bug: keep what was gathered, then report it
            log.exception("run failed at t = %.2f s", session.time_s)
            failure = f"{type(exc).__name__} at t = {session.time_s:.2f} s: {exc}"
            ctx.event("run_failed", message=failure)
        finally:
            bar.close()
            recorder.close_controller()
    summary = recorder.finish(out, scenario, ctx.events, network_files=network_files)
    if failure is not None:
        raise SimulationError(f"{failure} (outputs so far kept in {out})")
    if require_cavs is not None and not session.cav_ids:
        raise ConfigError(f"--cav-type: no vehicle of vType '{require_cavs}' ever departed")
    return summary
