"""Scenario configuration: TOML in, typed and validated dataclasses out.

Every section of a scenario file is a frozen dataclass. :func:`from_mapping` builds one from a
TOML table and refuses, with a :class:`~sumo_swarm.errors.ConfigError` naming the key and the
file, any unknown key, wrong type or out-of-range value (ranges are checked by each dataclass's
``__post_init__``). Nothing is silently ignored.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from sumo_swarm.checks import SEED_MAX, check_fields, is_number, require_number
from sumo_swarm.core.grid import GridSettings
from sumo_swarm.core.planner import PlannerSettings
from sumo_swarm.core.swarming.guards import GuardSettings
from sumo_swarm.core.tracking import LateralSettings, LongitudinalSettings
from sumo_swarm.errors import ConfigError

T = TypeVar("T")


# --------------------------------------------------------------------------- checks


# Thin names for the one range check (sumo_swarm.checks), as the settings classes read best:
# every named field (None skipped) must be a finite number > 0, or >= 0.
check_positive = functools.partial(check_fields, gt=0.0)
check_non_negative = functools.partial(check_fields, ge=0.0)


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class SimulationSettings:
    """How SUMO runs."""

    network: str = "../networks/highway3.net.xml"  # relative to the scenario file
    step_length_s: float = 0.03  # paper IV-C: time step 0.03 s
    duration_s: float = 80.0
    seed: int = 42
    lateral_resolution_m: float = 0.5  # sublane model; 0.5 m on 3 m lanes = 6 sublanes per lane
    route_edges: tuple[str, ...] = ("hwy",)

    def __post_init__(self) -> None:
        check_positive(self, "duration_s", "lateral_resolution_m")
        check_fields(self, "step_length_s", gt=0.0, le=1.0)
        check_fields(self, "seed", ge=0, le=SEED_MAX, integer=True)
        if not self.route_edges:
            raise ConfigError("route_edges must name at least one edge")


@dataclass(frozen=True)
class EvaluationSettings:
    """The window over which mobility and safety are measured (paper Section IV-E)."""

    start_s: float = 0.0
    end_s: float = 60.0
    travel_distance_m: float = 1000.0  # travel time = time for a CAV to cover this distance
    upstream_ranks: int = 5

    def __post_init__(self) -> None:
        check_non_negative(self, "start_s")
        check_positive(self, "end_s", "travel_distance_m", "upstream_ranks")
        if self.end_s <= self.start_s:
            raise ConfigError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")


@dataclass(frozen=True)
class OutputSettings:
    """SUMO's own outputs that a run asks for, and the network measures read from them
    (summary.json's ``network`` block, :mod:`sumo_swarm.sim.network`)."""

    # tripinfo with the emissions device, SSM conflicts (TTC) and edge data: what traffic
    # studies expect. They watch, they do not drive (a run's vehicles move the same with or
    # without them) and cost about a third more SUMO time; false: none of them.
    network: bool = True
    edge_data_period_s: float = 60.0  # the edge data's aggregation interval [s]
    ttc_threshold_s: float = 1.5  # a conflict is an encounter with a TTC below this [s]
    ssm_range_m: float = 50.0  # how far the SSM device looks for encounters (SUMO's default) [m]
    # SUMO's SSM device (the TTC conflicts) at all. It keeps every open encounter's samples in
    # memory for as long as the two vehicles stay within ssm_range_m: in a jam that is for as
    # long as the jam lasts, and SUMO's memory grows with it (an hour of the corridor under
    # sumo-cacc, which jams: 12.4 GB; without the device 0.4 GB for 900 s). false: no
    # network.ttc_below_1_5s_events; safety.min_ttc_s still comes from the trajectories.
    ssm: bool = True
    # The space-time speed field along the route, from the trajectories: cell length [m] and
    # period [s] (network_speed_field.parquet; sumo-swarm impact draws it per controller).
    speed_field_cell_m: float = 100.0
    speed_field_period_s: float = 10.0
    # Which rows trajectories.parquet gets: "all" vehicles at every step, or "cavs": the CAVs
    # and every vehicle within neighbour_range_m of one (straight-line distance), enough for
    # the summary's cav and overtake blocks; a network of thousands of vehicles then records a
    # few hundred. Hard brakes are counted for every vehicle either way; the upstream block,
    # the smallest TTC (safety.min_ttc_s) and the speed field see the recorded vehicles only.
    trajectories: Literal["all", "cavs"] = "all"
    neighbour_range_m: float = 200.0
    # Steps recorded: from record_from_s to record_to_s [s] of simulated time (None: the end).
    record_from_s: float = 0.0
    record_to_s: float | None = None
    # Recorded rows held in memory [rows]; beyond it the trajectories go to trajectories.parquet
    # chunk by chunk as they are recorded, and the summary is built from that file a slice of
    # steps at a time (sim/streamed.py): the same numbers, and a run's memory stops growing
    # with its length (an hour of the corridor is ~8 M rows, ~100 bytes each and as much
    # again for the summary's pairs). 1 M rows: 5 minutes of the corridor stay in memory.
    memory_rows: int = 1_000_000

    def __post_init__(self) -> None:
        check_positive(
            self,
            "edge_data_period_s",
            "ttc_threshold_s",
            "ssm_range_m",
            "speed_field_cell_m",
            "speed_field_period_s",
            "neighbour_range_m",
        )
        check_non_negative(self, "record_from_s")
        check_fields(self, "memory_rows", ge=1, integer=True)
        if self.record_to_s is not None and self.record_to_s <= self.record_from_s:
            raise ConfigError(
                f"record_to_s ({self.record_to_s}) must be after record_from_s "
                f"({self.record_from_s})"
            )


@dataclass(frozen=True)
class CavSettings:
    """The CAVs and the swarm's set points (paper IV-C)."""

    count: int = 6
    length_m: float = 5.0
    width_m: float = 1.8
    cruising_speed_mps: float = 20.0
    max_speed_mps: float = 25.0
    # Where the two speeds above come from. "config": these keys (the paper's 20 and 25 m/s).
    # "world": the user's world, updated every step: SUMO's desired speed of the CAVs where they
    # drive, min over the platoon of min(vType maxSpeed, lane limit * speedFactor) (what SUMO's
    # own drivers and sumo-cacc drive at), as both the cruising and the highest speed. A user's
    # sumocfg and attach() use "world" unless their config sets either speed; scenario files
    # default to "config".
    speeds: Literal["config", "world"] = "config"
    min_gap_m: float = 5.0  # minimum safety distance between CAVs
    desired_gap_m: float = 10.0  # desired safety distance between CAVs
    accel_min_mps2: float = -4.0
    accel_max_mps2: float = 3.0
    # Paper IV-C: "front wheel angle [-450 deg, 450 deg]" is evidently the steering-wheel range;
    # with a steering ratio of 15 that is +-30 deg at the wheels (see tracking.LateralSettings).
    steering_wheel_range_deg: float = 450.0
    steering_ratio: float = 15.0
    # The CAVs' lateral speed limit [m/s]: the trajectories plan lane changes under it, and every
    # CAV handed to the controllers gets it as its maxSpeedLat (SUMO caps changeSublane there;
    # a user's vType left at SUMO's default 1 m/s made each lane change take twice the time the
    # plan gave it).
    max_lateral_speed_mps: float = 2.0
    # With speeds = "world": "type" gives every CAV its vType's speedFactor (the mean of the
    # distribution SUMO draws from), so the platoon cruises at the lane limit times that one
    # factor; "vehicle" keeps SUMO's draw per CAV and the platoon cruises at its lowest (with
    # SUMO's default speedDev 0.1, five CAVs drew 0.83 on a 120 km/h road: 27.7 instead of
    # 33.3 m/s, while the same CAVs as SUMO drivers averaged 30.7 m/s).
    speed_factor: Literal["type", "vehicle"] = "type"
    wheelbase_m: float = 2.8

    def __post_init__(self) -> None:
        if self.count < 1:
            raise ConfigError(f"count must be >= 1 CAV, got {self.count}")
        check_positive(
            self,
            "length_m",
            "width_m",
            "cruising_speed_mps",
            "max_speed_mps",
            "min_gap_m",
            "desired_gap_m",
            "accel_max_mps2",
            "steering_wheel_range_deg",
            "steering_ratio",
            "max_lateral_speed_mps",
            "wheelbase_m",
        )
        if self.accel_min_mps2 >= 0:
            raise ConfigError(f"accel_min_mps2 must be < 0, got {self.accel_min_mps2}")
        if self.desired_gap_m < self.min_gap_m:
            raise ConfigError(
                f"desired_gap_m ({self.desired_gap_m}) must be >= min_gap_m ({self.min_gap_m})"
            )
        if self.max_speed_mps < self.cruising_speed_mps:
            raise ConfigError(
                f"max_speed_mps ({self.max_speed_mps}) must be >= cruising_speed_mps "
                f"({self.cruising_speed_mps})"
            )

    @property
    def wheel_angle_max_rad(self) -> float:
        return math.radians(self.steering_wheel_range_deg / self.steering_ratio)


@dataclass(frozen=True)
class IdmSettings:
    """Human-driven vehicles: SUMO's IDM with the parameters of Treiber, Hennecke & Helbing (2000).

    Treiber, Hennecke, Helbing, "Congested traffic states in empirical observations and microscopic
    simulations", Phys. Rev. E 62 (2000), Table I (highway): a = 0.73 m/s^2, b = 1.67 m/s^2,
    s0 = 2 m, delta = 4, v0 = 120 km/h. Its T = 1.6 s is replaced by the paper's "minimum
    car-following headway" of 1.2 s (IV-C), which is also what reproduces the paper's upstream
    gaps (23.9 m at 17.15 m/s, IV-E-4); set ``headway_s = 1.6`` for Treiber's value.
    """

    length_m: float = 5.0
    width_m: float = 1.8
    accel_mps2: float = 0.73  # a
    decel_mps2: float = 1.67  # b (comfortable deceleration)
    emergency_decel_mps2: float = 9.0
    headway_s: float = 1.2  # T
    min_gap_m: float = 2.0  # s0
    delta: float = 4.0
    desired_speed_mps: float = 33.33  # v0 = 120 km/h, for HVs that follow others
    lane_changes: bool = False  # paper: HVs keep their lanes

    def __post_init__(self) -> None:
        check_positive(
            self,
            "length_m",
            "width_m",
            "accel_mps2",
            "decel_mps2",
            "emergency_decel_mps2",
            "headway_s",
            "delta",
            "desired_speed_mps",
        )
        check_non_negative(self, "min_gap_m")


@dataclass(frozen=True)
class HvPlacement:
    """One explicitly placed human-driven vehicle."""

    id: str
    lane: int
    front_m: float  # front bumper along the route at t = 0 [m]
    speed_mps: float = 17.5
    desired_speed_mps: float | None = None  # None: IDM v0 of the HV settings
    length_m: float | None = None
    role: Literal["target", "adjacent", "other"] = "other"

    def __post_init__(self) -> None:
        if not self.id:
            raise ConfigError("id must not be empty")
        check_non_negative(self, "lane", "front_m", "speed_mps")
        check_positive(self, "desired_speed_mps", "length_m")


@dataclass(frozen=True)
class SceneSettings:
    """The scene of the paper's Figure 6 (all positions at t = 0, front bumpers along the route).

    The platoon drives in ``platoon_lane`` behind the slow ``target`` HV. HVs listed in ``hv``
    stand beside it; ``upstream_per_lane`` HVs follow, in every lane, the last vehicle of that
    lane at ``upstream_gap_m`` (paper IV-C: initial following distance of the upstream HVs 25 m).
    """

    platoon_lane: int = 1
    leader_front_m: float = 300.0
    initial_speed_mps: float = 17.5  # paper IV-C: speed of HVs 17.5 m/s
    initial_gap_m: float = 10.0  # CAV to CAV, and leader to the target HV
    upstream_per_lane: int = 5
    upstream_gap_m: float = 25.0
    upstream_speed_mps: float = 17.5
    hv: tuple[HvPlacement, ...] = ()

    def __post_init__(self) -> None:
        check_non_negative(self, "platoon_lane", "upstream_per_lane")
        check_positive(self, "leader_front_m", "initial_gap_m", "upstream_gap_m")
        check_non_negative(self, "initial_speed_mps", "upstream_speed_mps")
        ids = [h.id for h in self.hv]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"hv ids must be unique, got {ids}")
        if sum(h.role == "target" for h in self.hv) > 1:
            raise ConfigError("at most one hv may have role = 'target'")


@dataclass(frozen=True)
class CellLengthSettings:
    """Which rule sets the grid's cell length (the paper is inconsistent here).

    Paper II-B-1 sets l_cell = l_CAV + d_safe; its IV-C lists l_cell = 5 m, the vehicle length
    alone, which would put CAVs in adjacent rows bumper to bumper. Default: ``vehicle+desired_gap``
    (5 + 10 = 15 m), so a platoon in consecutive rows keeps the desired 10 m gap and tracking
    errors of a few metres still leave the 5 m minimum. ``vehicle+min_gap`` gives 10 m;
    ``fixed`` uses ``cell_length_m`` as given (5.0 is the paper's IV-C value).
    """

    rule: Literal["vehicle+desired_gap", "vehicle+min_gap", "fixed"] = "vehicle+desired_gap"
    cell_length_m: float = 5.0

    def __post_init__(self) -> None:
        check_positive(self, "cell_length_m")

    def resolve(self, cav: CavSettings) -> float:
        if self.rule == "vehicle+desired_gap":
            return cav.length_m + cav.desired_gap_m
        if self.rule == "vehicle+min_gap":
            return cav.length_m + cav.min_gap_m
        return self.cell_length_m


@dataclass(frozen=True)
class CaccSettings:
    """The longitudinal CACC law shared by the ``cacc`` baseline and the swarm's cruise mode.

    a = k_gap * (gap - d) + k_speed * (v_ahead - v) + k_accel * a_ahead, with
    d = desired_gap_m + time_gap_s * v, limited by the free-road law k_cruise * (v_cruise - v).
    Behind another CAV the free-road target rises by k_close * (gap - d) (capped at the CAV's
    max speed), so a follower that fell back can close up to a platoon cruising at v_cruise.
    """

    k_gap: float = 0.45
    k_speed: float = 1.1
    k_accel: float = 0.3
    k_cruise: float = 0.6
    k_close: float = 0.15  # [1/s] extra free-road speed per metre of excess gap behind a CAV
    time_gap_s: float = 0.0
    hv_time_gap_s: float = 0.0  # extra time gap when the vehicle ahead is human-driven

    def __post_init__(self) -> None:
        check_positive(self, "k_gap", "k_speed", "k_cruise")
        check_non_negative(self, "k_accel", "time_gap_s", "hv_time_gap_s", "k_close")


@dataclass(frozen=True)
class SwarmSettings:
    """When the swarm decides to overtake, and how it tracks its plan."""

    trigger_speed_ratio: float = 0.95  # leader held below this share of the cruising speed...
    trigger_after_s: float = 2.0  # ...for this long, by a slower vehicle ahead: overtake
    detect_range_m: float = 60.0  # the slower vehicle must be within this gap of the leader
    start_after_s: float = 1.0  # no overtaking decision before this time
    # A vehicle ahead accelerating harder than this [m/s^2] is getting up to speed (after a
    # merge), not a target.
    accelerating_mps2: float = 0.5
    # A slow vehicle is only catching up (not a target) when it and every vehicle ahead of it
    # in its lane within this [m] want at least the trigger speed (decision.only_catching_up).
    catching_up_ahead_m: float = 300.0
    # Progress of a manoeuvre, besides CAVs past the target or out of its lane: the CAVs still
    # behind it closer to passing it by this much in all [m] (give_up_no_progress_intervals).
    progress_step_m: float = 3.0
    # MPC re-solve period [s]; in between, the solved inputs are applied (zero-order hold on the
    # MPC's own 0.1 s step). 0.18 s = 6 SUMO steps at the paper's 0.03 s step: the tracking
    # error stays at 0.07 m RMS on the paper scene and a run costs half what 0.09 s costs.
    control_interval_s: float = 0.18
    control_interval_steps: int | None = None  # if set, the period in SUMO steps instead
    # Replan when a CAV is more than this many cells (rows + columns) away from both its planned
    # cell of the current behaving step and of the next one.
    drift_rows: float = 1.0
    regroup_lane: int | None = None  # None: the platoon's original lane
    # Grid speed once every CAV is past the target (paper II-B-1 Step 4 sets it to the front HV's
    # speed while overtaking and to a cruising speed otherwise). "target": keep the target's
    # speed until the swarm has regrouped (default: regroups on every network we tried);
    # "cruise": replan in a grid moving at the cruising speed (CAVs keep more speed while they
    # merge, but on a curved 3-lane road a CAV was left between lanes: see docs/closed-loop.md).
    regroup_grid_speed: Literal["target", "cruise"] = "target"
    # Who regroups the CAVs once every one is past the target. "planner": the cell MIP goes on
    # until they share the regroup lane (the paper's Fig. 6, step 4). "cruise": the manoeuvre
    # is complete when all are past, and the cruise mode re-forms the platoon in the fastest
    # lane it occupies (lane changes through the guards, CAVs in that lane opening gaps).
    # Default "cruise", a departure from the paper's step 4: the plan regroups in a grid moving
    # at the target's speed, so CAVs already past it slowed to the truck's speed and below
    # (9.6 m/s ahead of a 12 m/s truck, stress scene 95) to close up in the regroup lane. At
    # 15ef351, stress v2: completed and regrouped 86.4 -> 87.9 % where sumo-lc passes, gain
    # +19.6 -> +20.4 %, no scene worse by more than 0.3 points; paper-scene variants: 22 -> 29
    # of 40 pass every check (run cost <= 3x cacc in 28 -> 37: no planning after the pass).
    # Re-forming in the regroup lane after a pass (Reformer.prefer): the paper scene 20.49 m/s
    # (20.54), regrouped 32.2 s after the decision (35.8 s).
    regroup_by: Literal["planner", "cruise"] = "cruise"
    # With "planner": the manoeuvre is also complete once every CAV is past the target and they
    # form one platoon in any lane (the check of summary.json's "regrouped"), not only in the
    # regroup lane. A 3-lane road: all five CAVs were in the passing lane, 15 m apart, ahead of
    # a 15 m/s truck at 30 s; the plan then cut them back in front of it at the truck's speed
    # for 20 s. The cruise mode takes the platoon on (and moves it over as a unit if another
    # lane is faster). False: only in the regroup lane (the paper's Fig. 6 step 4).
    regroup_anywhere: bool = True
    # Hand the pass over to the cruise: once every CAV has left the target's lane and settled
    # in one other lane that is faster than the target by min_speed_gain_mps, the CAVs are a
    # platoon passing in that lane; when the lane's speed (at most the cruise) beats the
    # plan's pace (one cell per behaving interval above the grid) by min_speed_gain_mps, the
    # manoeuvre ends (event reason "passing_lane", not a give-up) and the cruise drives them
    # past at the lane's pace, as SUMO's drivers pass.
    # The plan moves them one cell per behaving interval relative to the target (5 m/s above
    # a truck with 15 m cells and 3 s): a 3-lane road at 900 veh/h/lane had all five CAVs in
    # the free middle lane at 20 m/s for 10 s beside a 15 m/s truck, lanes limited to 33 m/s.
    # False: the plan leads them past and regroups them (the paper's Fig. 6).
    hand_over_in_lane: bool = True
    # Pass in a faster lane as a unit, where that beats the cell plan: when a lane beside the
    # leader (its speed ahead, at most the cruise) is faster than the plan's pace past the
    # target (one cell per behaving interval above it) by min_speed_gain_mps and has room for
    # the platoon (within detect_range_m of its ends, a platoon's length of cells per vehicle
    # there; never the lane the target is moving into), the platoon moves over to that lane
    # ("overtake_start" with how = "lane"), each CAV through the lateral guard, entering
    # speeding up (entry_accel_mps2), and passes the target there at the lane's pace. Where
    # that stalls (a CAV still in the target's lane behind it, and no CAV out of that lane
    # or past the target for lane_pass_stall_s: no gaps) the cell plan takes over, blocking
    # and cutting through. Users' roads (33 m/s lanes, a 15 m/s truck): 0.70-0.93x sumo-lc's
    # CAV speed with the cells alone, 0.91-1.22x this way. False: always the cell plan (the
    # paper's method); with the paper's 20 m/s cruise beside a 15 m/s truck the plan's pace
    # is the cruise and the cells are kept.
    lane_pass: bool = True
    lane_pass_stall_s: float = 15.0
    # What a *free* lane (no HV beside the platoon or faster within detect_range_m behind it)
    # must beat by min_speed_gain_mps (decision.lane_pass_pace): "cells", the plan's pace as
    # above; "free" (default), the lower of that and the cruise less the gain: a lane free at
    # the cruise takes the platoon past together. With the paper's 20 m/s cruise the plan's
    # pace (19.4 m/s past a 14.4 m/s truck) left no lane pass at all: the cells took the CAVs
    # out one by one and the last met the stream that had come up the free lane meanwhile
    # (stress scenes 92, 192); SUMO's drivers all changed lanes at once, 60 m behind the truck.
    # A lane with HVs beside or behind the platoon keeps the plan's pace (with the free pace
    # there too, a car at 17.5 m/s coming up beside the platoon made the CAVs brake to 12 m/s
    # to let it by: stress scene 184). The paper's scene keeps its cells: HVs drive beside the
    # platoon in both side lanes.
    lane_pass_beats: Literal["cells", "free"] = "free"
    # A cruising CAV cut off from the platoon by a slow vehicle passes it on its own, in the
    # faster lane beside; it gives that up after this long [s] and heads for the platoon's lane
    # (not while it is alongside the slow vehicle in the passing lane: the pass goes on).
    max_pass_s: float = 30.0
    # A CAV whose lane change towards its goal (the side it passes in, or the platoon's lane)
    # the guard has refused for this long [s] in a row, with a slow vehicle ahead in its own
    # lane, tries the lane on its other side instead (event ``passing_switch``; 0 = never): a
    # CAV waited 30 s to pass a truck through a dense stream on its right while the lane on
    # its left was free (paper-scene variants with 9-11 CAVs).
    pass_switch_s: float = 6.0
    # Held towards its passing side for this long [s] already (0 = never), a CAV passing a
    # slow vehicle switches to the other side at once when the guard would let it in there
    # now, without waiting out pass_switch_s (not a CAV heading for the platoon's lane: it
    # would leave that lane): a CAV held 7 s towards a stream of 18 m/s traffic on its left
    # was still held there when the lane on its right, whose traffic had gone by, opened
    # (held-out variants: the last CAV of five behind the truck for 60 s).
    pass_open_side_s: float = 1.0
    # A CAV held this long [s] out of the platoon's lane beside a CAV of that lane whose front
    # is a little behind its own drops back behind that CAV (0 = never): neither counts the
    # other as ahead, and two CAVs at the same speed stayed side by side for 35 s (stress scenes
    # with regroup_by = "cruise"). Not at once: a CAV passing alongside for a moment braked for
    # nothing and slowed the CAVs behind it (stress scene 81: -1.2 m/s).
    drop_behind_s: float = 3.0
    # An HV that splits the platoon (a platoon CAV ahead of it in its lane) is passed by the
    # CAVs behind it when it drives below the cruise by min_speed_gain_mps less this [m/s]
    # (and a lane beside is faster by the gain), not only when it is as slow as a target
    # must be: it follows the platoon's front part, which eases off to close up (stress scene
    # 187: an HV at 18 m/s between four CAVs and five, 85 m apart, never passed). 0 = only
    # slow vehicles are passed (Reformer._splits).
    pass_intruder_mps: float = 1.0
    # A cruising CAV that has fallen back from the platoon CAV ahead of it, that CAV in another
    # lane, closes up as a CAV behind a CAV in its own lane does (cacc k_close per metre of
    # excess gap, at most the speed cap; decision.straggler_cruise). False: it cruises at the
    # platoon's speed, and a CAV that got past last, in the lane beside, stayed 150 m behind.
    catch_up_across_lanes: bool = True
    # A CAV refused a lane change out of a slow vehicle's lane into a faster one (stranded
    # behind the target after a give-up, or passing on its own) keeps this bumper gap [m]
    # behind the slow vehicle, and runs up towards the next lane's speed when a gap there would
    # take it at the speed it can reach (and still brake back behind the slow vehicle); 0 = it
    # waits at the slow vehicle's speed. Entering a stream 8 m/s faster at the truck's speed
    # makes the HV behind brake harder than b_safe at any gap the stream offers: stress scenes
    # left a CAV behind a 12 m/s truck for 36 s beside a lane at 20 m/s with 45-60 m headways.
    run_up_gap_m: float = 30.0
    # A CAV changing lanes in the cruise (re-forming, passing on its own) into a lane faster than
    # it by min_speed_gain_mps enters speeding up at this rate [m/s^2] to that lane's speed (at
    # most the cruise), and the lateral guard judges the HV behind by that: SUMO's drivers
    # enter a fast lane accelerating. Only with room to speed up behind the vehicle ahead in
    # its own lane during the lane change. 0: the guard assumes it keeps its speed.
    entry_accel_mps2: float = 1.5
    run_up_after_s: float = 2.0  # ...once the guard has held its lane change this long [s]
    # A run-up goes on this long [s] after the last step a gap would take the CAV (the HVs do
    # not drive at the constant speeds the look-ahead assumes; a run-up stopped half-way is
    # lost); dropping back to its run-up gap, a CAV slows at most run_up_drop_mps below the
    # slow vehicle [m/s].
    run_up_commit_s: float = 1.0
    run_up_drop_mps: float = 2.0
    # A CAV held this long [s] next to the platoon's lane by an HV that follows the platoon
    # there (at its speed, alongside or just behind the CAV) makes the whole platoon pull away
    # from that HV: every CAV cruises up to pull_away_mps [m/s] faster (at most the speed cap)
    # while the HV wants less than that, so the gap behind the CAV grows until the guard lets
    # it in. No HV is made to brake. Without it the CAV and the HV drove side by side at the
    # cruise for 30 s (stress scenes 17, 112: the platoon past the truck, never regrouped).
    # 0 = off.
    pull_away_after_s: float = 3.0
    pull_away_mps: float = 3.0
    # ...and where that HV wants more (it follows), after this long [s] the platoon re-forms in
    # the held CAVs' lane if it cruises as fast there (lane speeds at most the cruise, within
    # min_speed_gain_mps): the HV gets its lane back. Once per lane and edge; 0 = off.
    reform_switch_s: float = 6.0
    # A CAV stranded behind a slow vehicle, held this long [s] out of the lane beside by an HV
    # alongside it there, is helped by the platoon CAV that HV follows: it slows to
    # block_assist_mps [m/s] below the stranded CAV (the paper's blocking, while cruising;
    # Reformer._block_for_stranded). 0 = off.
    block_assist_after_s: float = 3.0
    block_assist_mps: float = 2.0
    # Overtake only when it pays: the swarm's speed cap (cav.max_speed_mps, the CAVs' vType
    # maxSpeed and the lane's limit for them, whichever is lowest) must exceed the target's speed
    # by at least this much [m/s]; the incentive criterion of MOBIL, for the whole platoon.
    # (Counted from the cap, not the cruise: passing at up to the cap, a swarm cruising at 20
    # m/s that overtook a car at 18.3 m/s drove 17% faster than one that stayed behind it.)
    # A car slower than the trigger speed that wants at least it, as does every vehicle ahead
    # of it in its lane within catching_up_ahead_m, is catching up, not a target
    # (decision.only_catching_up).
    min_speed_gain_mps: float = 2.0
    # "drivable": each behaving interval lasts at least one cell length at (cap - speed_margin -
    # grid speed), so a one-row move per interval never needs a speed above the cap (issue 11);
    # "fixed": the configured planner.behaving_interval_s always (the paper's 3 s, whatever the
    # speeds it needs: 15 m cells in 3 s need 5 m/s above the target).
    interval_rule: Literal["drivable", "fixed"] = "drivable"
    speed_margin_mps: float = 0.3  # room under the cap for tracking [m/s]
    # At most one replan per this long [s] unless a safety check demands one (a CAV left or
    # appeared, a new HV whose cells conflict with the plan, the plan ran out); None = one
    # behaving interval.
    replan_min_interval_s: float | None = None
    retry_after_s: float = 1.0  # after a failed replan, wait this long before the next [s]
    # Rolling horizon: while some CAV is still behind the target, check the last plan's HV
    # predictions every this many behaving intervals and replan when an HV in the grid is off
    # by more than prediction_error_m [m] (0 = only on the paper's events).
    replan_every_intervals: int = 1
    prediction_error_m: float = 4.0
    # A manoeuvre with no progress (CAVs past the target, rows gained) for this many behaving
    # intervals, or without a usable plan for give_up_no_plan_s, is given up: the CAVs re-form a
    # platoon and follow; no new decision for cooldown_s.
    give_up_no_progress_intervals: int = 6
    # With some CAVs past the target and the others stuck behind it, the ones past wait at the
    # target's speed in the passing lane (the paper's regroup), holding that lane back: give up
    # after this many intervals without progress instead, so they drive on and the ones behind
    # pass on their own (2-lane-change stress scenes: three CAVs at a truck's 14.4 m/s for 20 s).
    give_up_partial_intervals: int = 3
    # Give up once this many fresh plans in a row keep some CAVs in their cells behind the target
    # for the whole horizon while they take the others on (0 = never): the planner sees no way
    # past for them, and the CAVs past waited at the target's speed in the passing lane. After
    # the give-up the CAVs past drive on and the ones behind pass on their own, through the
    # guards (a 3-lane road at 900 veh/h/lane: two CAVs stranded from 14 s to 42 s).
    give_up_stranded_plans: int = 2
    # Give up once this many fresh plans in a row keep every CAV still behind the target in
    # its cell for the first give_up_waiting_s [s] (0 = never; reason "no_way_past"): the cell
    # planner sees a gap only that far ahead, if at all. Where a plan waited 24 s for a gap in
    # a stream 6 m/s faster than the target, the swarm gave up after 18 s without progress and
    # the CAVs then passed one by one through the guards within 5 s (stress v2: 27 first plans
    # waited 12 s or more; 25 of them ended in no_progress, 6 regrouped). While a plan waits
    # the swarm asks again every behaving interval (HVs entering the grid bring new gaps).
    give_up_waiting_plans: int = 2
    give_up_waiting_s: float = 12.0
    give_up_no_plan_s: float = 10.0
    cooldown_s: float = 15.0
    # After a give-up for no progress or stranded CAVs (not after failed plans: the platoon
    # then follows, the safe fallback) the leader too passes the target on its own for this
    # long [s] (the others already do, each once the CAV ahead is past), through the lateral
    # guard; 0 = the platoon follows the target until the next decision. Where the cells find
    # no way past together (a stream 15 m/s faster than the target in every other lane: 900
    # veh/h/lane), the CAVs get past as SUMO's own drivers do, one gap at a time, and re-form
    # ahead.
    pass_singly_s: float = 60.0
    # After a give-up that leaves the target between CAVs past it and CAVs behind it, the CAVs
    # past it wait for the others up to this long [s] (0 = they drive on): they re-form in its
    # lane ahead of it, where they hold up nobody but it, and keep its speed once they are
    # wait_lead_m ahead of the room the CAVs behind need to get in ahead of it (each a CAV
    # length plus cav.desired_gap_m, plus the target's secure gap by its model); the CAVs
    # behind it keep their lanes and pass it as they can, in any lane beside once the wait has
    # lasted pass_switch_s. The wait ends once every CAV is past and in one lane. Driving on,
    # the CAVs past were 190 m ahead when the last one got by, and the platoon was still in
    # two lanes when the run ended (variants 24, 27, 39). A choice of ours (the paper's swarm
    # never gives up): while it lasts, the CAVs past the target lose their speed above it.
    wait_ahead_s: float = 45.0
    # Waiting, the CAVs past the target keep up to this much more room [m] ahead of it than the
    # CAVs behind need (they slow to its speed only beyond it; cacc.k_close per metre): a CAV
    # that gets past soon after the give-up costs the others nothing, and one that gets past
    # late has this much to close at its catch-up speed. 0 = they hold just the room needed
    # (an earlier form of the wait, measured both ways: at 0, 34 variants passing the
    # overtake check and a mean CAV speed of 17.56 m/s; at 50 m, 33 and 17.71 m/s).
    wait_lead_m: float = 50.0
    # A CAV passing on its own is followed at once by the CAV behind it, in the same lane, once
    # its centre is in that lane (a train, as SUMO's drivers overtake); false = each CAV starts
    # its pass only once the CAV ahead is past the slow vehicle (5-6 s a CAV: platoons of 9-12
    # that gave up were still in two lanes 50 s later).
    pass_in_train: bool = True
    # A CAV passing a slow vehicle on its own judges the lanes beside over detect_range_m plus
    # this many seconds at the cruise [s]: the pass takes that long, and a slower vehicle just
    # beyond detect_range_m holds it there (variant 23: three CAVs passing a queued car in the
    # truck's lane, the truck 94 m ahead, ended behind the truck for 20 s and the platoon never
    # regrouped). 0 = detect_range_m only (the former rule; it passed 6 s sooner in one
    # held-out stress scene, where a car 2 m/s faster drove 100 m ahead in the passing lane).
    pass_reach_s: float = 5.0
    # A target that keeps right (its lane-change model's lcKeepRight > 0 and its lane-change
    # mode allows right-drive changes, read through libsumo) with the lane to its right free
    # is waited for up to this long [s] before the swarm starts: SUMO's drivers move over
    # within seconds, and a swarm that had started lost more re-forming than the plain platoon
    # lost waiting (13 stress scenes where the truck moved right at 8 s into the lane of the
    # CAV passing on its right: 1-7 % slower than cacc). For a target in the leftmost lane
    # (every pass of it takes the lane it is to move into), once seen so, the wait holds even
    # while that lane is taken for a moment (a car passing there): the swarm that started
    # then, 2 s in, filled the lane the truck was to move to, and the truck moved only at
    # 22 s, into a CAV's lane (stress scene 51, 3.8 % slower than cacc, whose truck moved at
    # 8 s). Not for a target with a lane on its left: there the swarm that passed at once was
    # faster than waiting (a paper-scene variant). 0 = start after trigger_after_s whatever
    # the target may do (the paper's HVs keep their lanes).
    keep_right_wait_s: float = 10.0
    # A target that keeps right with a lane on its left (not in the leftmost lane): "left", the
    # swarm starts at once and passes it on its left: its right lane, beside and behind it, is
    # closed to the cell plan while that lane is free for it to move into (up to
    # keep_right_wait_s from the start; plans.jsonl: "closed_lane"); "wait", waited for as one
    # in the leftmost lane; "go", started at once on either side. Waiting tied the plain platoon
    # exactly where a truck in the middle lane moved right 7-8 s in (stress v2: 10 scenes;
    # paper-scene variants 20, 21, 35); going at once on either side beat it by 1.2-2.9 % in
    # those, but a CAV put in the truck's right lane was cut off by it (stress scene 182, 3.2 %
    # slower than cacc).
    keep_right_middle: Literal["left", "wait", "go"] = "left"
    # A keep-right driver starts moving over this long [s] after the lane to its right is free
    # for it (SUMO's LC2013/SL2015: the wish builds over KEEP_RIGHT_TIME = 5 s at lcKeepRight
    # 1), if the follower there is then at least at its secure gap: the swarm waits for it only
    # where that holds with the follower closing in at its speed till then, and nothing slower
    # is within keep_right_ahead_s [s] ahead there (decision.right_lane_free).
    keep_right_move_s: float = 5.0
    # keep_right_due: the move comes sooner where SUMO's driver model says its wish will show
    # sooner: its keepRightProbability, read through libsumo, builds up towards the threshold
    # (decision.keep_right_due_s), and a driver that has built it up for 3 s moves 2 s later.
    # Each follower there is then judged as SUMO's lane-change check will see it: its own
    # minGap (not the CAVs' min_gap_m), and, speeding up, at its speed then. Judged 5 s ahead
    # with 5 m, a truck in the middle lane whose wish was 2 s away, with a car closing in at
    # 2.9 m/s 62 m behind it on its right, was judged unable to move over: the plan sent a
    # blocker into that lane, and the truck, which moved over at 7 s under cacc and sumo-lc,
    # stayed in the platoon's way until 17 s (a fresh variant of seed 23, 1 % slower than
    # cacc). false: keep_right_move_s from now with min_gap_m, whatever SUMO's state (and for
    # LC2013, whose reading is a whole number, always).
    keep_right_due: bool = True
    # With "left": while the target's driver wants to move right to keep right (SUMO's
    # lane-change state, read through libsumo: the wish it shows while that lane is taken, a
    # stream passing), its right lane is closed to the cell plan too, as long as the wish
    # lasts and that lane will open for it within keep_right_soon_s [s] (the HVs there driving
    # on at their speeds: decision.right_lane_opens_within). CAVs passing a truck on its right
    # just after a stream kept it from moving over (held-out variants 6, 8 and 24: 0.08-0.40
    # m/s slower than cacc; with 10 s, 6 is 0.19 faster, 8 and 24 are 0.11 and 0.25 slower).
    # Closed for as long as the wish lasted (keep_right_soon_s = 0), 8 passed too, but three
    # others whose stream went on for 60-90 s lost 1.2-1.7 m/s (10 s: at most 0.48).
    # keep_right_wish = false: the former rule, closed only while free, within
    # keep_right_wait_s of the start.
    keep_right_wish: bool = True
    keep_right_soon_s: float = 10.0
    keep_right_ahead_s: float = 4.0
    # An HV is held back by blockers for at most this long per manoeuvre [s] (the impact on
    # the traffic behind is bounded; the swarm gives up rather than hold a lane forever).
    max_block_s: float = 30.0
    max_leader_ease_mps: float = 2.0  # a cruising leader slows by at most this to close up [m/s]
    # ...and by up to this [m/s] when what follows it in its lane is a CAV of the platoon or
    # nothing within detect_range_m (no HV held back): CAVs that passed one by one in a lane
    # at the cap (users' 33 m/s roads) closed a 130 m stretch at 2 m/s in 65 s.
    regroup_ease_mps: float = 5.0
    # A CAV matches the speed of the lane its reference enters this far ahead [s].
    match_lookahead_s: float = 2.0
    hold_episode_s: float = 1.0  # lateral holds of one CAV closer together count once [s]
    # Lanes that end (an on-ramp's acceleration lane, a lane drop): no CAV moves into a lane
    # that ends within lane_end_hold_s at its speed, and a CAV whose lane ends within
    # lane_end_escape_s heads out of it (left first), both looking at least lane_end_min_m ahead
    # (an acceleration lane of netbuild's motorway is 250 m). No lane change within
    # lane_shift_hold_m [m] of a place where lane indices shift (a lane added or dropped on the
    # right): the vehicles on either side count their lanes differently there.
    lane_end_hold_s: float = 12.0
    lane_end_escape_s: float = 8.0
    lane_end_min_m: float = 300.0
    lane_shift_hold_m: float = 40.0
    # A CAV above the speed cap (it departed faster, a lower limit ahead) slows to it at this
    # rate [m/s^2], never by a jump in the commanded speed (SUMO would brake at its decel).
    cap_decel_mps2: float = 2.0
    in_lane_tolerance_m: float = 0.3  # a CAV is "in" a lane within this of its centre [m]

    def __post_init__(self) -> None:
        check_positive(
            self, "trigger_speed_ratio", "detect_range_m", "control_interval_s",
            "control_interval_steps",
        )  # fmt: skip
        check_non_negative(
            self, "trigger_after_s", "start_after_s", "drift_rows", "min_speed_gain_mps",
            "speed_margin_mps", "replan_min_interval_s", "retry_after_s", "give_up_no_plan_s",
            "cooldown_s", "pass_singly_s", "wait_ahead_s", "wait_lead_m", "max_block_s",
            "prediction_error_m",
            "max_leader_ease_mps", "regroup_ease_mps", "in_lane_tolerance_m", "match_lookahead_s",
            "hold_episode_s", "max_pass_s", "pass_switch_s", "pass_open_side_s", "drop_behind_s",
            "keep_right_wait_s",
            "give_up_waiting_s", "accelerating_mps2", "catching_up_ahead_m", "progress_step_m",
            "pass_reach_s",
            "run_up_commit_s", "run_up_drop_mps", "keep_right_move_s", "keep_right_soon_s",
            "keep_right_ahead_s", "lane_end_hold_s", "lane_end_escape_s", "lane_end_min_m",
            "lane_shift_hold_m",
        )  # fmt: skip
        check_positive(self, "cap_decel_mps2")
        check_non_negative(
            self,
            "give_up_waiting_plans",
            "give_up_stranded_plans",
            "run_up_gap_m",
            "run_up_after_s",
            "pull_away_after_s",
            "pull_away_mps",
            "reform_switch_s",
            "block_assist_after_s",
            "block_assist_mps",
            "entry_accel_mps2",
            "lane_pass_stall_s",
            "pass_intruder_mps",
        )
        check_fields(self, "give_up_no_progress_intervals", "give_up_partial_intervals", ge=1)


@dataclass(frozen=True)
class HvModelSettings:
    """How the swarm models the human drivers around it: one model for the planner's HV cells
    (eq. 15 and the blocking of eqs. 16-17), the HV prediction and the lateral guard.

    Each HV's car-following parameters are read from SUMO (accel, decel, tau, minGap, IDM's
    delta; a conservative bound for models other than IDM and Krauss), see
    :mod:`sumo_swarm.core.hvmodel`. A CAV may enter a lane in front of an HV only where that HV,
    reacting by its own model, brakes no harder than ``b_safe_mps2`` (MOBIL's b_safe, well inside
    the 4 m/s^2 hard-brake line). The planner plans against ``planner_share * b_safe_mps2`` so that
    the guard, which checks the true speeds against ``b_safe_mps2``, rarely has to refuse.

    ``margin_rule = "headway"`` keeps the paper's constant headway instead (grid.headway_s).
    """

    b_safe_mps2: float = 2.0
    planner_share: float = 0.7
    # The swarm regroups in front of the target no closer than where the target would brake
    # harder than this [m/s^2]: past it, the swarm must not hold the slow vehicle back.
    target_b_mps2: float = 0.3
    # A blocker that enters at a faster lane's speed then slows it at this share of the
    # planner's b_safe.
    block_decel_share: float = 0.7
    # Entry margins in front of an HV faster than the grid: a CAV speeds up towards that lane's
    # speed before it changes lanes (the tracker's speed matching), by up to this much above the
    # grid's speed [m/s], and then slows the lane to the grid's speed as a blocker does. The
    # margin is the gap at which the HV, reacting by its model, brakes no harder than b for
    # that whole entry; much smaller than for an entry at the grid's speed, so CAVs fit into the
    # gaps of a faster lane. 0: an entry at the grid's speed (the previous rule).
    entry_speed_gain_mps: float = 3.0
    margin_rule: Literal["model", "headway"] = "model"
    predictor: Literal["car-following", "constant-speed"] = "car-following"
    prediction_dt_s: float = 0.25

    def __post_init__(self) -> None:
        check_positive(
            self,
            "b_safe_mps2",
            "planner_share",
            "prediction_dt_s",
            "target_b_mps2",
            "block_decel_share",
        )
        require_number("entry_speed_gain_mps", self.entry_speed_gain_mps, ge=0.0)
        if self.planner_share > 1.0:
            raise ConfigError(f"planner_share must be <= 1, got {self.planner_share}")


@dataclass(frozen=True)
class PlatoonSettings:
    """How CAVs group into platoons, each a swarm that decides and overtakes on its own
    (:mod:`sumo_swarm.controllers.fleet`).

    ``grouping = "many"``: CAVs that meet in a lane form a platoon: a CAV joins a platoon whose
    CAV it follows (or leads) in its lane within ``join_gap_m`` (bumper to bumper); two platoons
    that meet so merge; none grows beyond ``max_size`` CAVs. A cruising platoon whose CAVs are
    strung out with a gap beyond ``split_gap_m`` between two of them (along the road, any lane)
    splits there. CAVs group only where they drive on the session's route frame, in a lane
    that goes on for ``exit_reach_s`` at their speed (at least ``exit_reach_min_m``), with
    their own exit no nearer; a CAV whose exit comes that near leaves its platoon (its route's
    lane changes are SUMO's, its speed our CACC's), as one on a ramp or in an acceleration lane
    stays out of them until it may join.
    Membership is reviewed every ``review_every_s``; a platoon in the middle of an overtake
    keeps its CAVs (but loses one that approaches its exit).

    ``grouping = "one"``: every CAV of the run is one swarm (the paper's scene; the behaviour
    before many swarms).
    """

    grouping: Literal["many", "one"] = "many"
    join_gap_m: float = 60.0
    # 12: the largest platoon of the paper's scene family (2-12 CAVs, scenarios/variants.toml)
    # stays one swarm, as before many swarms
    max_size: int = 12
    split_gap_m: float = 150.0
    review_every_s: float = 1.0
    exit_reach_s: float = 25.0
    exit_reach_min_m: float = 600.0
    # A swarm starts an overtake only where no other swarm's manoeuvre (its CAVs, its target,
    # its grid) is within this distance [m]: two swarms' grids never overlap.
    manoeuvre_clearance_m: float = 100.0

    def __post_init__(self) -> None:
        check_positive(
            self, "join_gap_m", "split_gap_m", "review_every_s", "exit_reach_s",
            "exit_reach_min_m",
        )  # fmt: skip
        require_number("manoeuvre_clearance_m", self.manoeuvre_clearance_m, ge=0.0)
        if self.max_size < 1:
            raise ConfigError(f"max_size must be >= 1 CAV, got {self.max_size}")
        if self.split_gap_m < self.join_gap_m:
            raise ConfigError(
                f"split_gap_m ({self.split_gap_m}) must be >= join_gap_m ({self.join_gap_m})"
            )


# Plain road a corridor keeps before its first ramp lane, between ramp lanes and after the last
# [m]: room for netconvert's junctions and for vehicles inserted upstream to settle.
CORRIDOR_MIN_PIECE_M = 100.0


def corridor_ramp_lanes(
    length_m: float,
    on_ramp_positions_m: tuple[float, ...],
    off_ramp_positions_m: tuple[float, ...],
    accel_lane_m: float,
    decel_lane_m: float,
) -> list[tuple[float, float, Literal["acc", "dec"], int]]:
    """``(start_m, end_m, kind, ramp number)`` of every ramp lane of a corridor, in driving
    order: an on-ramp's acceleration lane begins at its position, an off-ramp's deceleration
    lane ends at its. ConfigError naming the keys unless positions increase and every ramp lane
    lies on the road with :data:`CORRIDOR_MIN_PIECE_M` of plain road before, between and after.
    """
    for key, places in (
        ("on_ramp_positions_m", on_ramp_positions_m),
        ("off_ramp_positions_m", off_ramp_positions_m),
    ):
        if any(b <= a for a, b in itertools.pairwise(places)):
            raise ConfigError(f"{key}: positions must increase, got {list(places)}")
    lanes: list[tuple[float, float, Literal["acc", "dec"], int]] = [
        (x, x + accel_lane_m, "acc", i) for i, x in enumerate(on_ramp_positions_m)
    ]
    lanes += [(x - decel_lane_m, x, "dec", j) for j, x in enumerate(off_ramp_positions_m)]
    lanes.sort()

    def name(kind: str | None, number: int) -> str:
        if kind is None:
            return "the upstream end"
        ramp = "on" if kind == "acc" else "off"
        return f"the ramp lane of {ramp}_ramp_positions_m[{number}]"

    at, before = 0.0, name(None, 0)
    for start, end, kind, number in [*lanes, (length_m, length_m, None, -1)]:
        if start - at < CORRIDOR_MIN_PIECE_M - 1e-9:
            after = name(kind, number) if kind else "the downstream end"
            raise ConfigError(
                f"on_ramp_positions_m / off_ramp_positions_m: {start - at:g} m of plain road "
                f"between {before} and {after}; ramp lanes (accel_lane_m {accel_lane_m:g}, "
                f"decel_lane_m {decel_lane_m:g}) need at least {CORRIDOR_MIN_PIECE_M:g} m "
                f"before, between and after them on the road of length_m {length_m:g}"
            )
        at, before = end, name(kind, number)
    return lanes


@dataclass(frozen=True)
class CorridorSettings:
    """A motorway corridor scenario (``[corridor]``): the road, built by netconvert
    (:class:`sumo_swarm.sim.netbuild.CorridorSpec`, whose docstring lists the edge ids), and its
    traffic, written as ``<flow>``s (:mod:`sumo_swarm.sim.scene`). Without ``[corridor]`` a
    scenario is the paper's placed scene on ``simulation.network``.

    The traffic: ``main_demand_vph_per_lane`` enters at the upstream end and each on-ramp adds
    its ``on_ramp_demands_vph``; ``cav_share`` and ``truck_share`` of every demand are CAVs and
    trucks, the rest cars. Cars are SUMO's default passenger vType (Krauss, sigma 0.5, tau 1 s,
    a new user's traffic) with SUMO's default speed spread (``speed_dev``); ``[hv]`` (the paper's
    IDM drivers) is not used for them. Every vehicle departs in the best lane at the highest safe
    speed. Times: flows run from 0 to ``simulation.duration_s``; the road starts empty (about
    ``length_m`` / 30 m/s to fill), so a study measures after a warm-up (``[evaluation]
    start_s``; the window is the whole run unless ``[evaluation]`` sets it).
    """

    # The road. Positions are metres from the upstream end along the main road.
    length_m: float = 6000.0
    lanes: int = 3  # through lanes (the swarm needs 2 or more)
    speed_limit_mps: float = 33.33  # 120 km/h, a common European motorway limit
    lane_width_m: float = 3.5  # the usual motorway lane (RAA, AASHTO ~3.6 m); SUMO's default 3.2
    # Where each on-ramp joins, i.e. its acceleration lane begins (the merge nose), in order.
    on_ramp_positions_m: tuple[float, ...] = ()
    # veh/h entering from each on-ramp (one per on-ramp position).
    on_ramp_demands_vph: tuple[float, ...] = ()
    # Where each off-ramp leaves, i.e. its deceleration lane ends (the diverge nose), in order.
    off_ramp_positions_m: tuple[float, ...] = ()
    # Share (0..1) of the traffic passing on the main road just upstream of each off-ramp that
    # leaves there (a turning ratio: it applies to the main demand and to earlier on-ramps'
    # traffic alike; traffic entering downstream of an off-ramp cannot take it).
    off_ramp_shares: tuple[float, ...] = ()
    # Parallel-type ramp lanes: 250 m is the usual acceleration lane of German (RAA, E1) and
    # similar guidelines; the deceleration lane is taken as long. Ramps are one lane.
    accel_lane_m: float = 250.0
    decel_lane_m: float = 250.0
    ramp_length_m: float = 300.0  # each ramp's own edge, off the main road
    ramp_speed_limit_mps: float = 22.22  # 80 km/h on the ramps
    # The traffic.
    main_demand_vph_per_lane: float = 1500.0  # at the upstream end [veh/h per through lane]
    cav_share: float = 0.2  # of every demand (main and ramps); CAVs are cars
    truck_share: float = 0.15  # of every demand; the usual heavy-vehicle share of a motorway
    # Trucks are semi-trailers (SUMO's vClass "trailer": 16.5 m, accel 1 m/s^2). Their desired
    # speed is truck_desired_speed_mps times SUMO's speed factor (mean 1, spread speed_dev: about
    # 20.7-25 m/s), capped at truck_max_speed_mps: the EU's 80 km/h truck limit as trucks drive
    # it (about 83 km/h) and the 90 km/h speed limiter (EU directive 92/6/EEC).
    truck_desired_speed_mps: float = 23.0
    truck_max_speed_mps: float = 25.0
    # SUMO's speed-factor spread (its default 0.1) of cars and trucks; the run's
    # --default.speeddev 0 would otherwise take it away. CAVs keep one speed (their vType).
    speed_dev: float = 0.1
    # Departures: "poisson" (exponential headways: random arrivals, as traffic counts show) or
    # "uniform" (evenly spaced vehicles of each flow).
    arrivals: Literal["poisson", "uniform"] = "poisson"

    def __post_init__(self) -> None:
        check_positive(
            self, "length_m", "speed_limit_mps", "lane_width_m", "accel_lane_m", "decel_lane_m",
            "ramp_length_m", "ramp_speed_limit_mps", "truck_desired_speed_mps",
            "truck_max_speed_mps",
        )  # fmt: skip
        check_non_negative(self, "main_demand_vph_per_lane", "speed_dev")
        check_fields(self, "lanes", ge=2, integer=True)
        for key in ("cav_share", "truck_share"):
            check_fields(self, key, ge=0.0, le=1.0)
        if self.cav_share + self.truck_share > 1.0 + 1e-9:
            raise ConfigError(
                f"cav_share ({self.cav_share}) + truck_share ({self.truck_share}) must be <= 1"
            )
        if self.truck_max_speed_mps < self.truck_desired_speed_mps:
            raise ConfigError(
                f"truck_max_speed_mps ({self.truck_max_speed_mps}) must be >= "
                f"truck_desired_speed_mps ({self.truck_desired_speed_mps})"
            )
        pairs = (
            ("on_ramp_positions_m", "on_ramp_demands_vph"),
            ("off_ramp_positions_m", "off_ramp_shares"),
        )
        for where, what in pairs:
            if len(getattr(self, where)) != len(getattr(self, what)):
                raise ConfigError(
                    f"{what} needs one value per entry of {where}: got "
                    f"{len(getattr(self, what))} for {len(getattr(self, where))}"
                )
        for i, demand in enumerate(self.on_ramp_demands_vph):
            require_number(f"on_ramp_demands_vph[{i}]", demand, ge=0.0)
        for i, share in enumerate(self.off_ramp_shares):
            require_number(f"off_ramp_shares[{i}]", share, ge=0.0, le=1.0)
        for i, x in enumerate((*self.on_ramp_positions_m, *self.off_ramp_positions_m)):
            n_on = len(self.on_ramp_positions_m)
            key = f"on_ramp_positions_m[{i}]" if i < n_on else f"off_ramp_positions_m[{i - n_on}]"
            require_number(key, x, gt=0.0)
        if self.main_demand_vph_per_lane + sum(self.on_ramp_demands_vph) <= 0.0:
            raise ConfigError("main_demand_vph_per_lane and on_ramp_demands_vph are all 0")
        corridor_ramp_lanes(
            self.length_m, self.on_ramp_positions_m, self.off_ramp_positions_m,
            self.accel_lane_m, self.decel_lane_m,
        )  # fmt: skip


@dataclass(frozen=True)
class Scenario:
    """A whole scenario file."""

    name: str
    path: Path
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    evaluation: EvaluationSettings = field(default_factory=EvaluationSettings)
    outputs: OutputSettings = field(default_factory=OutputSettings)
    cav: CavSettings = field(default_factory=CavSettings)
    hv: IdmSettings = field(default_factory=IdmSettings)
    scene: SceneSettings = field(default_factory=SceneSettings)
    cell: CellLengthSettings = field(default_factory=CellLengthSettings)
    grid: GridSettings = field(default_factory=GridSettings)
    # [planner]: every key is a PlannerSettings field (core/planner/problem.py documents them).
    # Speed: network_work (exact min-cost-flow search, 20000 arcs x flows), network_only (true:
    # its best plan when it does not finish, no CP-SAT), time_limit_s (wall safety net, 0.25 s).
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    cacc: CaccSettings = field(default_factory=CaccSettings)
    swarm: SwarmSettings = field(default_factory=SwarmSettings)
    platoons: PlatoonSettings = field(default_factory=PlatoonSettings)
    hvmodel: HvModelSettings = field(default_factory=HvModelSettings)
    guards: GuardSettings = field(default_factory=GuardSettings)
    longitudinal: LongitudinalSettings = field(default_factory=LongitudinalSettings)
    lateral: LateralSettings = field(default_factory=LateralSettings)
    # [corridor]: a motorway corridor with ramps and a demand (CorridorSettings) instead of the
    # paper's placed scene on simulation.network; None: no corridor.
    corridor: CorridorSettings | None = None

    def __post_init__(self) -> None:
        # One source for each physical quantity: the cell length comes from [cell], the CAV
        # length, wheelbase and steering range from [cav] (the planner's grid and the lateral
        # MPC read them from here; the loader refuses them in [grid] and [lateral]).
        grid = dataclasses.replace(
            self.grid, cell_length_m=self.cell_length_m, cav_length_m=self.cav.length_m
        )
        delta = self.cav.wheel_angle_max_rad
        lateral = dataclasses.replace(
            self.lateral, wheelbase_m=self.cav.wheelbase_m, delta_min=-delta, delta_max=delta
        )
        object.__setattr__(self, "grid", grid)
        object.__setattr__(self, "lateral", lateral)

    @property
    def network_path(self) -> Path:
        return (self.path.parent / self.simulation.network).resolve()

    @property
    def cell_length_m(self) -> float:
        return self.cell.resolve(self.cav)


def union_members(tp: Any) -> tuple[Any, ...]:
    """The alternatives of a type hint: ``(A, B)`` for ``A | B`` or ``Optional``; ``(tp,)``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return (tp,)


# Each section's settings class (an optional section, such as [corridor], by its class).
SECTIONS = {
    name: next(a for a in union_members(tp) if a is not type(None))
    for name, tp in typing.get_type_hints(Scenario).items()
    if name not in ("name", "path")
}


# Keys of the shared settings classes that a scenario sets elsewhere (one source for each).
DERIVED_KEYS = {
    "grid": {"cell_length_m": "[cell] (rule, cell_length_m)", "cav_length_m": "cav.length_m"},
    "lateral": {
        "wheelbase_m": "cav.wheelbase_m",
        "delta_min": "cav.steering_wheel_range_deg / cav.steering_ratio",
        "delta_max": "cav.steering_wheel_range_deg / cav.steering_ratio",
    },
}

# --------------------------------------------------------------------------- loader


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def nested_dataclass(tp: Any) -> tuple[Literal["table", "items"], type] | None:
    """What a field of type ``tp`` holds below it in a scenario file: ``("table", cls)`` for a
    (possibly optional) dataclass, ``("items", cls)`` for a list of dataclasses, else None."""
    for arg in union_members(tp):
        if dataclasses.is_dataclass(arg):
            return "table", typing.cast(type, arg)
        if typing.get_origin(arg) is tuple:
            items = typing.get_args(arg)
            if items and dataclasses.is_dataclass(items[0]):
                return "items", typing.cast(type, items[0])
    return None


def _convert(value: Any, tp: Any, key: str) -> Any:
    """Check ``value`` against the annotation ``tp`` and convert it (TOML -> dataclass field)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    members = union_members(tp)
    if len(members) > 1:
        if value is None and type(None) in members:
            return None
        errors = []
        for arg in members:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{key}: unexpected value {value!r}")
    if origin is Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise ConfigError(f"{key}: must be one of {choices}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: expected a list, got {type(value).__name__}")
        item_tp = args[0] if args else Any
        return tuple(_convert(v, item_tp, f"{key}[{i}]") for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {type(value).__name__}")
        return from_mapping(tp, value, prefix=key)
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not is_number(value):  # TOML has nan and inf; no setting means either
            raise ConfigError(f"{key}: expected a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise ConfigError(f"{key}: expected {_type_name(tp)}, got {value!r}")


def from_mapping(cls: type[T], data: dict[str, Any], prefix: str = "") -> T:
    """Build dataclass ``cls`` from ``data``: unknown keys, wrong types and bad values raise.

    ``prefix`` is the dotted key path of ``data`` in its file, used in error messages.
    """
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    dotted = f"{prefix}." if prefix else ""
    unknown = sorted(set(data) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields))
        raise ConfigError(f"unknown key '{dotted}{unknown[0]}' (known: {known})")
    kwargs = {name: _convert(value, hints[name], f"{dotted}{name}") for name, value in data.items()}
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None
    except TypeError as exc:  # a required field is missing
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """The tables of a TOML file; ConfigError naming the file when missing, unreadable, bad."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{what} not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: malformed TOML: {exc}") from None


def load_scenario(
    path: str | Path,
    overrides: dict[str, dict[str, Any]] | None = None,
    *,
    require_network: bool = True,
) -> Scenario:
    """Load and validate a scenario TOML file.

    ``overrides`` maps section names to key/value pairs applied over the file (used by sweeps).
    Any problem raises ConfigError whose message names the key and the file.
    ``require_network=False`` accepts settings files for the plugin API, which have no network.
    """
    path = Path(path)
    data = read_toml(path, "scenario file")
    for section, values in (overrides or {}).items():
        data.setdefault(section, {}).update(values)
    try:
        name = data.pop("name", path.stem)
        if not isinstance(name, str) or not name:
            raise ConfigError("name: expected a non-empty string")
        unknown = sorted(set(data) - set(SECTIONS))
        if unknown:
            raise ConfigError(
                f"unknown section '[{unknown[0]}]' (known: {', '.join(sorted(SECTIONS))})"
            )
        for section, keys in DERIVED_KEYS.items():
            for key, source in keys.items():
                if key in data.get(section, {}):
                    raise ConfigError(f"{section}.{key} is not set here: it comes from {source}")
        sections = {key: _convert(value, SECTIONS[key], key) for key, value in data.items()}
        if "corridor" in sections:
            sections.update(_corridor_sections(data, sections))
        scenario = Scenario(name=name, path=path.resolve(), **sections)
        # A settings file for a user's sumocfg or attach() runs at SUMO's step, not this file's
        # (unless the file names one): the behaving interval is not checked against it.
        step_given = require_network or "step_length_s" in data.get("simulation", {})
        _check_consistency(scenario, step_given=step_given)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    if require_network and scenario.corridor is None:  # a corridor builds its network
        if not scenario.network_path.is_file():
            raise ConfigError(
                f"{path}: simulation.network: file not found: {scenario.network_path}"
            )
        _check_network(scenario, path)
    return scenario


# What a corridor scenario does not use: its network is built and its vehicles flow in.
CORRIDOR_UNUSED = {
    "simulation.network": "the corridor's network is built from [corridor]",
    "simulation.route_edges": "the route frame is the corridor's main road",
    "scene": "the corridor's vehicles enter as flows",
}


def _corridor_sections(data: dict[str, Any], sections: dict[str, Any]) -> dict[str, Any]:
    """The sections a corridor changes: ``[evaluation]`` over the whole run unless the file
    sets its end. ConfigError for a key a corridor does not use (nothing silently ignored)."""
    for key, why in CORRIDOR_UNUSED.items():
        section, _, name = key.partition(".")
        if section in data and (not name or name in data[section]):
            raise ConfigError(f"{key} is not used with [corridor]: {why}")
    changed: dict[str, Any] = {}
    if "end_s" not in data.get("evaluation", {}):
        duration = sections.get("simulation", SimulationSettings()).duration_s
        evaluation = sections.get("evaluation", EvaluationSettings())
        changed["evaluation"] = dataclasses.replace(evaluation, end_s=duration)
    return changed


def _check_network(sc: Scenario, path: Path) -> None:
    """The route's edges exist, have at least two lanes, and hold every lane the scene uses."""
    from sumo_swarm.safexml import parse_xml

    net = sc.network_path
    try:
        root = parse_xml(net, what="SUMO network")
    except ConfigError as exc:
        raise ConfigError(f"{path}: simulation.network: {exc}") from None
    lanes = {
        e.get("id"): len(e.findall("lane"))
        for e in root.iter("edge")
        if e.get("function") != "internal"
    }
    for edge in sc.simulation.route_edges:
        if edge not in lanes:
            raise ConfigError(f"{path}: simulation.route_edges: no edge '{edge}' in {net}")
    first = lanes[sc.simulation.route_edges[0]]
    if first < 2:
        raise ConfigError(
            f"{path}: simulation.network: the road has {first} lane; the swarm needs at least 2"
        )
    used = [("scene.platoon_lane", sc.scene.platoon_lane)]
    used += [(f"scene.hv '{h.id}'.lane", h.lane) for h in sc.scene.hv]
    for key, lane in used:
        if lane >= first:
            raise ConfigError(f"{path}: {key} = {lane}, but the road has lanes 0..{first - 1}")


def _check_consistency(sc: Scenario, *, step_given: bool = True) -> None:
    """Cross-section checks that no single section can make (the step-length one only where
    the scenario's step is the simulation's: ``step_given``)."""
    if sc.cell_length_m < sc.cav.length_m:
        raise ConfigError(
            f"cell.cell_length_m: a cell ({sc.cell_length_m} m) must be at least as long as a "
            f"CAV ({sc.cav.length_m} m)"
        )
    if sc.evaluation.end_s > sc.simulation.duration_s:
        raise ConfigError(
            f"evaluation.end_s ({sc.evaluation.end_s}) is after simulation.duration_s "
            f"({sc.simulation.duration_s})"
        )
    interval = sc.planner.behaving_interval_s
    steps = interval / sc.simulation.step_length_s
    if step_given and abs(steps - round(steps)) > 1e-6:
        raise ConfigError(
            f"planner.behaving_interval_s ({interval}) must be a whole number of "
            f"simulation.step_length_s ({sc.simulation.step_length_s})"
        )
