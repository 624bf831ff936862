"""One headless run: scenario + controller -> SUMO -> trajectories.parquet and summary.json."""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from sumo_swarm.bridge import SumoSession
from sumo_swarm.config import Scenario
from sumo_swarm.controllers import make_controller
from sumo_swarm.controllers.base import Controller, RunContext
from sumo_swarm.errors import ConfigError, SimulationError
from sumo_swarm.scene import CAV_TYPE, sumo_options, write_sumo_inputs
from sumo_swarm.summary import build_summary

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


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON through a temporary file and a rename: a crash never leaves half a file."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def write_parquet_atomic(path: Path, df: pd.DataFrame) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, path)


def trajectory_frame(session: SumoSession) -> pd.DataFrame:
    df = pd.DataFrame(session.record.columns)
    if not df.empty:
        df["kind"] = df["kind"].astype("category")
        df["vehicle"] = df["vehicle"].astype("category")
        df["edge"] = df["edge"].astype("category")
        df["lane"] = df["lane"].astype("int16")
    return df


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
    out = prepare_out_dir(out_dir)
    if seed is not None:
        scenario = replace(scenario, simulation=replace(scenario.simulation, seed=seed))
    controller = controller or make_controller(controller_name)
    cfg, scene = write_sumo_inputs(scenario, controller_name, out / "sumo")
    args = ["-c", str(cfg), *sumo_options(scenario)]
    if fcd:
        args += ["--fcd-output", str(out / "fcd.xml"), "--fcd-output.acceleration", "true"]
    cav_ids = scene.cav_ids
    sim = scenario.simulation
    wall0 = time.perf_counter()
    sumo_s = 0.0
    controller_s = 0.0
    n_steps = round(sim.duration_s / sim.step_length_s)
    session = SumoSession(
        args,
        route_edges=sim.route_edges,
        is_cav=lambda vid, type_id: type_id == CAV_TYPE,
        gui=gui,
    )
    failure: str | None = None
    with session:
        road = session.road_section(sim.route_edges[0])
        ctx = RunContext(session, scenario, cav_ids, road, out_dir=out)
        controller.attach(ctx)
        bar = tqdm(
            total=n_steps, desc=f"{scenario.name}/{controller_name}", unit="step",
            disable=(not progress) if progress is not None else None, leave=False,
        )  # fmt: skip
        try:
            for _ in range(n_steps):
                t0 = time.perf_counter()
                session.step()
                t1 = time.perf_counter()
                controller.control(session.time_s)
                t2 = time.perf_counter()
                sumo_s += t1 - t0
                controller_s += t2 - t1
                bar.update()
                if not session.has_vehicles_to_come():
                    break
        except SimulationError as exc:
            failure = str(exc)
            ctx.event("sumo_failed", message=failure)
        finally:
            bar.close()
    wall = time.perf_counter() - wall0
    df = trajectory_frame(session)
    write_parquet_atomic(out / "trajectories.parquet", df)
    write_events(out / "events.jsonl", ctx.events)
    timing = {
        "wall_s": wall,
        "sumo_s": sumo_s,
        "controller_s": controller_s,
        "realtime_factor": (session.time_s / wall) if wall > 0 else None,
    }
    summary = build_summary(
        scenario=scenario,
        controller=controller_name,
        df=df,
        scene=scene,
        session=session,
        controller_summary=controller.summary(),
        timing=timing,
    )
    write_json_atomic(out / "summary.json", summary)
    if failure is not None:
        raise SimulationError(f"{failure} (outputs so far kept in {out})")
    return summary


def write_events(path: Path, events: list[dict[str, Any]]) -> None:
    with path.open("w", encoding="utf-8") as fh:
        for e in events:
            fh.write(json.dumps(e, default=str) + "\n")
