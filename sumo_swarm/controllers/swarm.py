"""The swarm controller: the paper's method closed around SUMO.

Each SUMO step (after the step, acting on the next one):

1. *Cruise* as a CACC platoon until the leader is held below the cruising speed by a slower
   vehicle ahead for ``swarm.trigger_after_s``: that vehicle becomes the target.
2. *Overtake*: build the moving grid around the target, solve the cell MIP, validate the plan,
   turn every CAV's cells into a smooth reference (eqs. 20-22), and track it with the
   longitudinal (time-domain) and lateral (spatial-domain) MPCs on OSQP. Replan on the events
   of the paper's Fig. 4 (new HV in the grid, plan executed) and on drift.
3. When every CAV is past the target and back in the regroup lane, *cruise* again.

Command path (why speed + sublane moves, not moveToXY): ``setSpeed`` makes SUMO integrate the
CAV's true speed, so IDM followers see a real leader and brake for a CAV that moves in ahead
of them (that is how blocking works), and ``changeSublane`` moves the CAV sideways through the
sublane model, so SUMO assigns it to the lanes it overlaps while it moves. ``moveToXY`` teleports
the vehicle each step and lets SUMO derive a speed from the displacement, which hides the
commanded speed from the car-following logic for a step and replaces the route when the spot is
off it. Measured on the paper scene: see docs/closed-loop.md.

Safety layers under the plan, each recorded as an event when it acts:
* a gap guard caps the tracked acceleration so no CAV closes within ``cav.min_gap_m`` of any
  vehicle ahead in the lanes it overlaps or is moving into;
* a lateral guard holds a CAV in its lane while the lane it is moving into has a vehicle
  closer than the minimum gap ahead or a follower closer than ``guard_headway_s`` behind;
* SUMO's own safe-speed check stays on (speed mode 31);
* when the planner fails or times out, the last valid plan is kept while it lasts, else the
  CAVs fall back to CACC following in their current lanes.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np

from sumo_swarm.controllers.base import RunContext
from sumo_swarm.controllers.cacc import command_cacc
from sumo_swarm.grid import MovingGrid, build_grid, cav_cell
from sumo_swarm.metrics import lateral_rms, summarise_ms
from sumo_swarm.model import VehicleState
from sumo_swarm.neighbours import ordered_platoon, vehicle_ahead, vehicle_behind
from sumo_swarm.planner import (
    CellPlanner,
    Plan,
    ReplanTrigger,
    build_problem,
    make_planner,
    validate_plan,
)
from sumo_swarm.tracking import LateralMpc, LongitudinalMpc
from sumo_swarm.trajectory import GridFrame, Reference, reference_from_cells

log = logging.getLogger(__name__)

CRUISE, OVERTAKE = "cruise", "overtake"
GUARD_GAP_GAIN = 0.8  # [1/s^2] gap guard: a <= k_g (gap - d) + k_v (v_ahead - v)
GUARD_SPEED_GAIN = 1.5  # [1/s]
# Lateral guard: a CAV holds its lane while the follower in the lane it would enter is closer
# than an IDM driver's desired gap: min gap + GUARD_HEADWAY_S * v + v * dv / (2 sqrt(a b)),
# with a reference a = 1 m/s^2 and b = 2 m/s^2 (GUARD_IDM_SQRT_AB). The closing-speed term is
# what makes IDM brake hard: in the stress sweep, HVs at 21.5 m/s braked at -5.7 to -9 m/s^2
# for CAVs (14.5 m/s) cutting in 23-29 m ahead, where a kinematic check saw only ~1 m/s^2.
GUARD_HEADWAY_S = 1.0
GUARD_IDM_SQRT_AB = 2.0**0.5
IN_LANE_TOL_M = 0.3  # a CAV is "in" a lane when its centre is this close to the lane centre [m]
MAX_LEADER_EASE_MPS = 2.0  # a cruising leader slows by at most this to let the platoon close up
RETRY_AFTER_S = 1.0  # after a failed replan, wait this long before the next replan [s]
LANE_END_LENGTH_M = 1000.0  # length of the pseudo-obstacle standing for a lane that ends [m]
MARGIN_RELAXATION = (1.0, 0.5, 0.0)  # HV margin scales tried in turn when a replan is infeasible


class SwarmController:
    """The method of the paper: cruise, swarm past a slow vehicle, regroup, cruise."""

    name = "swarm"

    def __init__(self, planner: CellPlanner | None = None) -> None:
        """``planner`` replaces the planner built from the scenario's ``[planner]`` section."""
        self.ctx: RunContext | None = None
        self._planner_override = planner
        self.mode = CRUISE
        self.target_id: str | None = None
        self.slow_since_s: float | None = None
        self.plan: Plan | None = None
        self.grid: MovingGrid | None = None
        self.references: dict[str, Reference] = {}
        self.phi: dict[str, float] = {}
        self.configured: set[str] = set()
        self.solve_ms: list[float] = []
        self.statuses: Counter[str] = Counter()
        self.fallbacks = 0
        self.lat_errors: list[float] = []
        self.t_start_s: float | None = None
        self.t_done_s: float | None = None
        self.overtakes = 0
        self.passed = False
        self.regroup_lane_used: int | None = None
        self._plans_file = None
        self.replan_not_before_s = -math.inf
        self.last_plan_s = -math.inf
        self.inputs: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        self.mpc_ms: list[float] = []
        self._step_count = 0

    # ------------------------------------------------------------------ set-up
    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        sc = ctx.scenario
        self.grid_settings = replace(
            sc.grid, cell_length_m=sc.cell_length_m, cav_length_m=sc.cav.length_m
        )
        self.planner_settings = sc.planner
        if sc.swarm.regroup_lane is not None:
            self.planner_settings = replace(sc.planner, regroup_lane=sc.swarm.regroup_lane)
        self.planner = self._planner_override or make_planner(self.planner_settings)
        self.trigger = ReplanTrigger(drift_cells=1)
        self.lon_settings = sc.longitudinal
        self.lat_settings = sc.lateral
        self.lon_mpc: dict[str, LongitudinalMpc] = {}
        self.lat_mpc: dict[str, LateralMpc] = {}
        if ctx.out_dir is not None:
            self._plans_file = (ctx.out_dir / "plans.jsonl").open("w", encoding="utf-8")

    def _configure_new(self, states: dict[str, VehicleState]) -> None:
        ctx = self.ctx
        for vid in ctx.cav_ids:
            if vid in states and vid not in self.configured:
                ctx.session.configure_cav(vid)
                self.configured.add(vid)
                self.phi[vid] = 0.0
                self.lon_mpc[vid] = LongitudinalMpc(self.lon_settings)
                self.lat_mpc[vid] = LateralMpc(self.lat_settings)

    # ------------------------------------------------------------------ main step
    def control(self, t_s: float) -> None:
        try:
            self._control(t_s)
        except Exception as exc:  # never let a bug of ours crash the user's simulation
            log.exception("swarm controller failed at t = %.2f s", t_s)
            self.ctx.event("controller_error", message=f"{type(exc).__name__}: {exc}")
            if self.mode == OVERTAKE:
                self._finish(t_s, completed=False)
            states = self.ctx.session.states
            self._cruise(states, ordered_platoon(states, self.ctx.cav_ids))

    def _control(self, t_s: float) -> None:
        ctx = self.ctx
        states = ctx.session.states
        self._configure_new(states)
        platoon = ordered_platoon(states, ctx.cav_ids)
        if not platoon:
            return
        road = ctx.session.road_at(platoon[0])
        if road is not None:
            ctx.road = road
        if self.mode == CRUISE:
            target = self._slow_vehicle_ahead(t_s, states, platoon)
            if target is not None:
                self._start_overtake(t_s, target)
        if self.mode == OVERTAKE:
            if self.target_id not in states:
                ctx.event("target_left", target=self.target_id)
                self._finish(t_s, completed=False)
            elif self._overtake_done(states, platoon):
                self._finish(t_s, completed=True)
            else:
                self._maybe_replan(t_s, states, platoon)
        if self.mode == OVERTAKE and self.plan is not None:
            self._track(t_s, states, platoon)
        else:
            self._cruise(states, platoon)

    # ------------------------------------------------------------------ cruise
    def _slow_vehicle_ahead(
        self, t_s: float, states: dict[str, VehicleState], platoon: list[str]
    ) -> VehicleState | None:
        """The target once the leader has been held back long enough (see SwarmSettings)."""
        sw = self.ctx.scenario.swarm
        cav = self.ctx.scenario.cav
        if self.ctx.road.n_lanes < 2 or t_s < sw.start_after_s:
            return None
        leader = states[platoon[0]]
        ahead = vehicle_ahead(leader, states.values(), self.ctx.road)
        slow = cav.cruising_speed_mps * sw.trigger_speed_ratio
        if (
            ahead is None
            or ahead[0].is_cav
            or ahead[1] > sw.detect_range_m
            or ahead[0].speed_mps >= slow
            or leader.speed_mps >= slow
        ):
            self.slow_since_s = None
            return None
        if self.slow_since_s is None:
            self.slow_since_s = t_s
        if t_s - self.slow_since_s + 1e-9 < sw.trigger_after_s:
            return None
        return ahead[0]

    def _cruise(self, states: dict[str, VehicleState], platoon: list[str]) -> None:
        """CACC following in the current lane, drifting back to the lane centre."""
        ctx = self.ctx
        sc = ctx.scenario
        dt = ctx.dt_s
        # A stretched platoon regroups from both ends: followers may exceed the cruising speed
        # (cacc_accel), and the leader eases off by k_close per metre of excess gap behind it,
        # which is what closes up a platoon whose CAVs cannot go faster than the cruise speed.
        stretch = 0.0
        for front, back in itertools.pairwise(platoon):
            f, b = states[front], states[back]
            if f.lane == b.lane:
                stretch += max(0.0, f.rear_s_m - b.s_m - sc.cav.desired_gap_m)
        leader_cruise = sc.cav.cruising_speed_mps - min(
            MAX_LEADER_EASE_MPS, sc.cacc.k_close * stretch
        )
        command_cacc(ctx, platoon, leader_cruise)
        for vid in platoon:
            ego = states[vid]
            step = sc.cav.max_lateral_speed_mps * dt
            ctx.session.change_sublane(vid, float(np.clip(-ego.lat_m, -step, step)))
            self.phi[vid] = 0.0

    # ------------------------------------------------------------------ overtake
    def _start_overtake(self, t_s: float, target: VehicleState) -> None:
        self.mode = OVERTAKE
        self.target_id = target.vehicle_id
        self.overtakes += 1
        if self.t_start_s is None:
            self.t_start_s = t_s
        self.plan = None
        self.passed = False
        self.trigger = ReplanTrigger(drift_cells=1)
        self.ctx.event("overtake_start", target=target.vehicle_id)

    def _finish(self, t_s: float, completed: bool) -> None:
        self.mode = CRUISE
        self.plan = None
        self.references = {}
        self.slow_since_s = None
        if completed and self.t_done_s is None:
            self.t_done_s = t_s
        self.ctx.event("overtake_end", target=self.target_id, completed=completed)

    def _overtake_done(self, states: dict[str, VehicleState], platoon: list[str]) -> bool:
        target = states[self.target_id]
        road = self.ctx.road
        lane = self._regroup_lane(target)
        y_lane = road.lane_centre_y(lane)
        gap = self.ctx.scenario.cav.min_gap_m
        for vid in platoon:
            cav = states[vid]
            if cav.rear_s_m < target.s_m + gap:
                return False
            if abs(road.y_of(cav.lane, cav.lat_m) - y_lane) > IN_LANE_TOL_M:
                return False
        return True

    def _all_past(self, states: dict[str, VehicleState], platoon: list[str]) -> bool:
        """Every CAV's rear is ahead of the target's front by the minimum gap."""
        target = states[self.target_id]
        gap = self.ctx.scenario.cav.min_gap_m
        return all(states[v].rear_s_m >= target.s_m + gap for v in platoon)

    def _regroup_lane(self, target: VehicleState) -> int:
        lane = self.planner_settings.regroup_lane
        self.regroup_lane_used = target.lane if lane is None else lane
        return self.regroup_lane_used

    def _maybe_replan(self, t_s: float, states: dict[str, VehicleState], platoon: list[str]):
        ctx = self.ctx
        grid = self.grid
        hv_ids: list[str] = []
        cells: dict[str, tuple[int, int]] = {}
        if grid is not None and self.plan is not None:
            for vid, st in states.items():
                if st.is_cav:
                    continue
                row = grid.row_of(st.centre_s_m, t_s)
                if 0 <= row < grid.n_rows:
                    hv_ids.append(vid)
            cells = {vid: cav_cell(grid, states[vid], ctx.road, t_s) for vid in platoon}
        reason = self.trigger.check(t_s, cells, hv_ids) if self.plan is not None else "initial"
        if (
            self.plan is not None
            and not self.passed
            and ctx.scenario.swarm.regroup_grid_speed == "cruise"
            and self._all_past(states, platoon)
        ):
            self.passed = True
            reason = "passed"  # regroup in a grid moving at the cruising speed (Step 4)
        if self.plan is not None and set(platoon) != set(self.plan.cav_ids):
            ctx.event("cav_set_changed", planned=list(self.plan.cav_ids), present=platoon)
            reason = "cav_set_changed"
        if self.plan is None and self.trigger.plan is not None and reason is None:
            return  # the last solve failed; the trigger says when to retry
        if reason is None or (reason != "initial" and t_s < self.replan_not_before_s):
            return
        if reason == "drift" and t_s - self.last_plan_s < self.planner_settings.behaving_interval_s:
            return  # give the tracker one behaving interval to converge before replanning
        self._replan(t_s, reason, states, platoon)

    def _replan(self, t_s: float, reason: str, states: dict[str, VehicleState], platoon):
        ctx = self.ctx
        sc = ctx.scenario
        target = states[self.target_id]
        cavs = [states[v] for v in platoon]
        hvs = [s for v, s in states.items() if not s.is_cav and v != self.target_id]
        hvs += self._lane_ends(cavs[-1].rear_s_m, target.s_m + 400.0)
        # Paper II-B-1, Step 4: the grid moves with the front HV while the swarm overtakes it,
        # at the cruising speed otherwise (here: once every CAV is past it, to regroup).
        cruise_grid = sc.swarm.regroup_grid_speed == "cruise" and self._all_past(states, platoon)
        grid_speed = sc.cav.cruising_speed_mps if cruise_grid else target.speed_mps
        record: dict[str, Any] = {"time_s": t_s, "trigger": reason, "grid_speed_mps": grid_speed}
        grid = problem = plan = None
        violations: list[str] = []
        try:
            # Mid-manoeuvre a CAV may sit inside an HV's headway margin (it cut in as
            # planned, and the HV has not fallen back yet), which makes the full-margin problem
            # infeasible: relax the margins step by step, down to the physical footprint.
            for level, scale in enumerate(MARGIN_RELAXATION):
                gs = replace(
                    self.grid_settings,
                    headway_s=self.grid_settings.headway_s * scale,
                    gap_behind_m=self.grid_settings.gap_behind_m * scale,
                )
                grid = build_grid(cavs, target, ctx.road, t_s, grid_speed, gs)
                problem = build_problem(grid, cavs, hvs, target, t_s, self.planner_settings, gs)
                plan = self.planner.plan(problem)
                record["margin_scale"] = scale
                if plan.ok or plan.status.value != "infeasible":
                    break
                if level == 0 and reason == "initial":
                    break  # the first plan is made with the full margins or not at all
            violations = validate_plan(problem, plan) if plan.ok else []
        except Exception as exc:  # a planner bug must never stop the simulation
            log.exception("planning failed")
            plan = None
            record.update(status="error", message=str(exc))
        if plan is not None:
            self.solve_ms.append(plan.solve_ms)
            self.statuses[plan.status.value] += 1
            record.update(
                status=plan.status.value, solve_ms=plan.solve_ms, objective=plan.objective,
                blockers=plan.blockers, violations=violations,
                cells={c: list(map(list, plan.cells_of(c))) for c in plan.cav_ids}
                if plan.ok else None,
                grid={"origin_s_m": grid.origin_s_m, "t0_s": grid.t0_s,
                      "speed_mps": grid.speed_mps, "cell_length_m": grid.cell_length_m,
                      "n_rows": grid.n_rows, "n_cols": grid.n_cols},
            )  # fmt: skip
        else:
            self.statuses["error"] += 1
        self._write_plan(record)
        if plan is not None and plan.ok and not violations:
            self.plan, self.grid = plan, grid
            self.last_plan_s = t_s
            self.trigger.planned(plan, t_s, problem.hv_ids)
            frame = GridFrame(
                grid.origin_s_m, t_s, grid.speed_mps, grid.cell_length_m,
                self.planner_settings.behaving_interval_s, ctx.road,
            )  # fmt: skip
            self.references = {}
            self.inputs = {}
            for vid in platoon:
                st = states[vid]
                self.references[vid] = reference_from_cells(
                    plan.cells_of(vid), frame, ctx.road,
                    a_min=sc.cav.accel_min_mps2, a_max=sc.cav.accel_max_mps2,
                    v_max=sc.cav.max_speed_mps,
                    max_lat_speed_mps=0.9 * sc.cav.max_lateral_speed_mps,
                    t_now=t_s, s_now=st.centre_s_m, y_now=ctx.road.y_of(st.lane, st.lat_m),
                    v_now=st.speed_mps, a_now=st.accel_mps2,
                )  # fmt: skip
            return
        # Failed, timed out or invalid: keep the last valid plan while it lasts, else CACC.
        self.fallbacks += 1
        self.replan_not_before_s = t_s + RETRY_AFTER_S
        ctx.event("planner_fallback", trigger=reason, status=record.get("status"),
                  kept_last_plan=self.plan is not None and reason != "plan_done")  # fmt: skip
        if self.plan is not None and reason not in ("plan_done",):
            self.trigger.planned(self.plan, self.trigger.planned_at_s or t_s, hv_ids_of(problem))
            return
        self.plan = None
        failed = plan if plan is not None else None
        if failed is not None:
            self.trigger.planned(failed, t_s, ())

    def _lane_ends(self, s_from_m: float, s_to_m: float) -> list[VehicleState]:
        """Lanes that end ahead (a later route edge has fewer lanes), as standing obstacles.

        Each is a pseudo-vehicle at speed 0 covering the lane from its end onwards, so the
        planner keeps CAVs out of the vanishing lane in time and the swarm regroups before it.
        """
        session = self.ctx.session
        platoon = ordered_platoon(session.states, self.ctx.cav_ids)
        edge = session.edges.get(platoon[0]) if platoon else None
        out = []
        for lane, end in session.lanes_ending(edge, s_from_m, s_to_m) if edge else []:
            out.append(
                VehicleState(f"lane_end:{lane}@{end:.0f}", end + LANE_END_LENGTH_M, lane, 0.0,
                             0.0, LANE_END_LENGTH_M)
            )  # fmt: skip
        return out

    def _write_plan(self, record: dict[str, Any]) -> None:
        if self._plans_file is not None:
            self._plans_file.write(json.dumps(record, default=_json_default) + "\n")
            self._plans_file.flush()

    # ------------------------------------------------------------------ tracking
    def _track(self, t_s: float, states: dict[str, VehicleState], platoon: list[str]) -> None:
        ctx = self.ctx
        sc = ctx.scenario
        road = ctx.road
        dt = ctx.dt_s
        others = list(states.values())
        lon, lat = self.lon_settings, self.lat_settings
        solve_now = self._step_count % self.ctx.scenario.swarm.control_interval_steps == 0
        self._step_count += 1
        for vid in platoon:
            ego = states[vid]
            ref = self.references.get(vid)
            if ref is None:
                continue
            centre = ego.centre_s_m
            y = road.y_of(ego.lane, ego.lat_m)
            if solve_now or vid not in self.inputs:
                # Longitudinal, time domain.
                _, s_ref, v_ref, _ = ref.sample_time(t_s, lon.dt_s, lon.horizon)
                res = self.lon_mpc[vid].solve(centre, ego.speed_mps, s_ref, v_ref)
                # Lateral, spatial domain: distance steps from the current speed.
                ds = max(ego.speed_mps, 1.0) * lat.dt_s
                _, y_ref, dy_ref, _ = ref.sample_space(centre, ds, lat.horizon)
                kappa = np.full(lat.horizon, road.curvature_1pm)
                lres = self.lat_mpc[vid].solve(
                    y, self.phi[vid], y_ref, np.arctan(dy_ref), kappa, ds
                )
                self.inputs[vid] = (t_s, res.inputs, lres.inputs)
                self.mpc_ms.append(res.solve_ms + lres.solve_ms)
            # Between solves, apply the solved input sequences (zero-order hold on dt_s).
            t_solved, accels, deltas = self.inputs[vid]
            accel = float(accels[min(int((t_s - t_solved) / lon.dt_s + 1e-9), len(accels) - 1)])
            delta = float(deltas[min(int((t_s - t_solved) / lat.dt_s + 1e-9), len(deltas) - 1)])
            self.lat_errors.append(y - ref.y_at_s(centre))
            # The lateral move of this SUMO step from the kinematic model (eqs. 33-35).
            ds_step = ego.speed_mps * dt
            phi = self.phi[vid]
            proposed = ds_step * math.sin(phi)
            dlat = self._lateral_guard(ego, y, proposed, others)
            if dlat != proposed:  # held by the guard: stop turning towards the other lane
                phi = 0.0
            else:
                phi = phi + ds_step * (math.tan(delta) / sc.cav.wheelbase_m - road.curvature_1pm)
            self.phi[vid] = phi
            accel = min(accel, self._gap_guard(ego, y, y + dlat, others))
            accel = min(max(accel, sc.cav.accel_min_mps2), sc.cav.accel_max_mps2)
            ctx.session.set_speed(vid, ego.speed_mps + accel * dt)
            ctx.session.change_sublane(vid, dlat)

    def _gap_guard(self, ego: VehicleState, y_now: float, y_next: float, others) -> float:
        """Largest acceleration that keeps the minimum gap to whatever is ahead [m/s^2]."""
        cav = self.ctx.scenario.cav
        limit = math.inf
        for y in {y_now, y_next}:
            ahead = vehicle_ahead(ego, others, self.ctx.road, y_m=y)
            if ahead is None:
                continue
            lead, gap = ahead
            d = cav.min_gap_m + 1.0
            a = GUARD_GAP_GAIN * (gap - d) + GUARD_SPEED_GAIN * (lead.speed_mps - ego.speed_mps)
            limit = min(limit, a)
        return limit

    def _lateral_guard(self, ego: VehicleState, y: float, dlat: float, others) -> float:
        """Hold the lateral move while the lane it enters is not safe (returns the move)."""
        road = self.ctx.road
        if abs(dlat) < 1e-6:
            return dlat
        lane_now = road.lane_of_y(y)
        lane_next = road.lane_of_y(y + dlat + math.copysign(0.9, dlat))
        if lane_next == lane_now:
            return dlat
        y_probe = road.lane_centre_y(lane_next)
        cav = self.ctx.scenario.cav
        ahead = vehicle_ahead(ego, others, road, y_m=y_probe)
        behind = vehicle_behind(ego, others, road, y_m=y_probe)
        unsafe = ahead is not None and ahead[1] < cav.min_gap_m
        if behind is not None:
            follower, gap = behind
            need = (
                cav.min_gap_m
                if follower.is_cav
                else max(cav.min_gap_m, GUARD_HEADWAY_S * follower.speed_mps)
            )
            if not follower.is_cav:
                closing = max(0.0, follower.speed_mps - ego.speed_mps)
                need += follower.speed_mps * closing / (2.0 * GUARD_IDM_SQRT_AB)
            unsafe = unsafe or gap < need
        if unsafe:
            self.ctx.event("lateral_hold", vehicle=ego.vehicle_id, lane=lane_next)
            return 0.0
        return dlat

    # ------------------------------------------------------------------ outputs
    def close(self) -> None:
        """Close plans.jsonl (the run is over or the swarm was detached)."""
        if self._plans_file is not None:
            self._plans_file.close()
            self._plans_file = None

    def summary(self) -> dict[str, Any]:
        interval = self.planner_settings.behaving_interval_s if self.ctx else 3.0
        steps = None
        if self.t_start_s is not None and self.t_done_s is not None:
            steps = math.ceil((self.t_done_s - self.t_start_s) / interval - 1e-9)
        return {
            "overtake": {
                "regroup_lane": self.regroup_lane_used,
                "triggered": self.t_start_s is not None,
                "target": self.target_id,
                "t_start_s": self.t_start_s,
                "behaving_steps": steps,
            },
            "planner": {
                "solves": len(self.solve_ms),
                **summarise_ms(self.solve_ms, prefix="solve_ms_"),
                "statuses": dict(self.statuses),
                "fallbacks": self.fallbacks,
            },
            "lat_error_rms_m": lateral_rms(self.lat_errors),
            "mpc": summarise_ms(self.mpc_ms, prefix="solve_ms_per_cav_"),
        }


def hv_ids_of(problem) -> tuple[str, ...]:
    return tuple(problem.hv_ids) if problem is not None else ()


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple | set | frozenset):
        return list(obj)
    return str(obj)
