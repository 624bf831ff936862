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

from sumo_swarm.checks import SEED_MAX, check_fields, is_number, require_number, unknown_name
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
    """How SUMO runs.

    Attributes
    ----------
    network
        The SUMO network file, relative to the scenario file; a copied file whose network is not
        beside it falls back to the built-in network of that name.
    step_length_s
        SUMO's step length [s] (the paper: 0.03 s; the swarm runs at 1 s, SUMO's default, or
        less; the baselines at any step).
    duration_s
        How long the simulation runs [s].
    seed
        SUMO's random seed [1].
    lateral_resolution_m
        SUMO's sublane resolution [m], which lateral control needs (0.5 m on 3 m lanes: 6 sublanes
        a lane).
    route_edges
        The edges of the route the scene is placed along, in order.
    """

    network: str = field(
        default="../networks/highway3.net.xml", metadata={"range": "a SUMO .net.xml file"}
    )
    step_length_s: float = 0.03
    duration_s: float = 80.0
    seed: int = 42
    lateral_resolution_m: float = 0.5
    route_edges: tuple[str, ...] = field(
        default=("hwy",), metadata={"range": "edges of the network, 2 lanes or more"}
    )

    def __post_init__(self) -> None:
        check_positive(self, "duration_s", "lateral_resolution_m")
        check_fields(self, "step_length_s", gt=0.0)
        check_fields(self, "seed", ge=0, le=SEED_MAX, integer=True)
        if not self.route_edges:
            raise ConfigError("route_edges must name at least one edge")


@dataclass(frozen=True)
class EvaluationSettings:
    """The window over which mobility and safety are measured (paper Section IV-E).

    Attributes
    ----------
    start_s
        Start of the window over which mobility and safety are measured [s].
    end_s
        End of that window [s].
    travel_distance_m
        A CAV's travel time is the time it takes to cover this distance [m].
    upstream_ranks
        How many HVs behind the swarm in each lane are ranked in the upstream block [vehicles].
    """

    start_s: float = 0.0
    end_s: float = 60.0
    travel_distance_m: float = 1000.0
    upstream_ranks: int = 5

    def __post_init__(self) -> None:
        check_non_negative(self, "start_s")
        check_positive(self, "end_s", "travel_distance_m", "upstream_ranks")
        if self.end_s <= self.start_s:
            raise ConfigError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")


@dataclass(frozen=True)
class OutputSettings:
    """SUMO's own outputs that a run asks for, and the network measures read from them
    (summary.json's ``network`` block, :mod:`sumo_swarm.sim.network`).

    Attributes
    ----------
    network
        Ask SUMO for tripinfo (with emissions) and edge data, count TTC conflicts, and fill
        summary.json's network block from them.
    edge_data_period_s
        The edge data's aggregation interval [s].
    ttc_threshold_s
        A conflict is an encounter with a time to collision below this [s].
    ssm_range_m
        How far SUMO's SSM device looks for encounters [m].
    ssm
        Also run SUMO's SSM device and keep its conflicts (network_conflicts.parquet). Off by
        default: it holds every step of every open encounter in memory, which grows with a
        jam's length (11.6-12 GB over the corridor's hour); the summary's TTC conflicts are
        counted from the run's own steps either way (sim/conflicts.py).
    speed_field_cell_m
        Cell length of the space-time speed field along the route [m].
    speed_field_period_s
        Period of the space-time speed field [s].
    trajectories
        Rows of trajectories.parquet: every vehicle at every step, or the CAVs and the vehicles
        within neighbour_range_m of one.
    neighbour_range_m
        With trajectories = "cavs", how far (straight line) from a CAV a vehicle is recorded [m].
    record_from_s
        Record steps from this simulated time on [s].
    record_to_s
        Record steps up to this simulated time [s] (none: to the end).
    memory_rows
        Recorded rows held in memory; beyond it the rows go to disk chunk by chunk and the summary
        reads them back [rows].
    """

    network: bool = True
    edge_data_period_s: float = 60.0
    ttc_threshold_s: float = 1.5
    ssm_range_m: float = 50.0
    ssm: bool = False
    speed_field_cell_m: float = 100.0
    speed_field_period_s: float = 10.0
    trajectories: Literal["all", "cavs"] = "all"
    neighbour_range_m: float = 200.0
    record_from_s: float = 0.0
    record_to_s: float | None = field(default=None, metadata={"range": "> record_from_s; none"})
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


# The most CAVs a scene may place: 10000 CAVs of 5 m at 10 m gaps are 150 km of platoon, more
# than any road a scene departs on; a count of 10**11 allocated before SUMO started.
MAX_CAVS = 10_000


@dataclass(frozen=True)
class CavSettings:
    """The CAVs and the swarm's set points (paper IV-C).

    Attributes
    ----------
    count
        Number of CAVs in the scene [CAVs].
    length_m
        CAV length [m].
    width_m
        CAV width [m].
    cruising_speed_mps
        The swarm's cruising speed [m/s].
    max_speed_mps
        The highest speed a CAV may drive [m/s].
    speeds
        Where the two speeds above come from: these keys ("config") or SUMO's desired speed of the
        CAVs where they drive ("world", the default on a user's sumocfg).
    min_gap_m
        Minimum safety distance between CAVs [m].
    desired_gap_m
        Desired safety distance between CAVs [m].
    accel_min_mps2
        Strongest braking a CAV is commanded [m/s²].
    accel_max_mps2
        Strongest acceleration a CAV is commanded [m/s²].
    steering_wheel_range_deg
        Steering-wheel angle range, plus or minus [deg] (the paper's "front wheel angle [-450, 450]
        deg").
    steering_ratio
        Steering ratio: the front-wheel angle is the steering-wheel angle divided by it [1].
    max_lateral_speed_mps
        The CAVs' lateral speed limit, given to SUMO as their maxSpeedLat [m/s].
    speed_factor
        With speeds = "world": every CAV gets its vType's speedFactor ("type") or keeps SUMO's draw
        ("vehicle").
    wheelbase_m
        Wheelbase of the lateral model [m].
    """

    count: int = 6
    length_m: float = 5.0
    width_m: float = 1.8
    cruising_speed_mps: float = 20.0
    max_speed_mps: float = 25.0
    speeds: Literal["config", "world"] = "config"
    min_gap_m: float = 5.0
    desired_gap_m: float = 10.0
    accel_min_mps2: float = -4.0
    accel_max_mps2: float = 3.0
    steering_wheel_range_deg: float = 450.0
    steering_ratio: float = 15.0
    max_lateral_speed_mps: float = 2.0
    speed_factor: Literal["type", "vehicle"] = "type"
    wheelbase_m: float = 2.8

    def __post_init__(self) -> None:
        check_fields(self, "count", ge=1, le=MAX_CAVS)
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
        check_fields(self, "accel_min_mps2", lt=0.0)
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

    Attributes
    ----------
    length_m
        HV length [m].
    width_m
        HV width [m].
    accel_mps2
        IDM maximum acceleration a [m/s²].
    decel_mps2
        IDM comfortable deceleration b [m/s²].
    emergency_decel_mps2
        SUMO's emergency deceleration of the HVs [m/s²].
    headway_s
        IDM time headway T [s].
    min_gap_m
        IDM standstill gap s0 [m].
    delta
        IDM acceleration exponent delta [1].
    desired_speed_mps
        IDM desired speed v0 of HVs that follow others [m/s].
    lane_changes
        Let the HVs change lanes (the paper's HVs keep their lanes).
    """

    length_m: float = 5.0
    width_m: float = 1.8
    accel_mps2: float = 0.73
    decel_mps2: float = 1.67
    emergency_decel_mps2: float = 9.0
    headway_s: float = 1.2
    min_gap_m: float = 2.0
    delta: float = 4.0
    desired_speed_mps: float = 33.33
    lane_changes: bool = False

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
    """One explicitly placed human-driven vehicle.

    Attributes
    ----------
    id
        The HV's SUMO id.
    lane
        Its lane (0: rightmost) [lane].
    front_m
        Its front bumper along the route at t = 0 [m].
    speed_mps
        Its speed at t = 0 [m/s].
    desired_speed_mps
        Its IDM desired speed [m/s] (none: [hv] desired_speed_mps).
    length_m
        Its length [m] (none: [hv] length_m).
    role
        Its role in the paper's scene: the slow target, an HV adjacent to the platoon, or other.
    """

    id: str = field(metadata={"range": "a vehicle id, unique in the scene"})
    lane: int
    front_m: float
    speed_mps: float = 17.5
    desired_speed_mps: float | None = None
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

    Attributes
    ----------
    platoon_lane
        Lane of the CAV platoon at the start (0: rightmost) [lane].
    leader_front_m
        Front bumper of the platoon's leader along the route at t = 0 [m].
    initial_speed_mps
        Speed of every vehicle at t = 0 [m/s].
    initial_gap_m
        Gap from CAV to CAV, and from the leader to the target HV, at t = 0 [m].
    upstream_per_lane
        HVs placed behind the platoon in each lane [vehicles].
    upstream_gap_m
        Gap between the upstream HVs [m].
    upstream_speed_mps
        Speed of the upstream HVs at t = 0 [m/s].
    """

    platoon_lane: int = 1
    leader_front_m: float = 300.0
    initial_speed_mps: float = 17.5
    initial_gap_m: float = 10.0
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

    Attributes
    ----------
    rule
        How the planner's cell length is set: CAV length plus desired gap, CAV length plus minimum
        gap, or cell_length_m.
    cell_length_m
        The cell length with rule = "fixed" [m].
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

    Attributes
    ----------
    k_gap
        CACC gain on the gap error [1/s²].
    k_speed
        CACC gain on the speed difference to the vehicle ahead [1/s].
    k_accel
        CACC gain on the vehicle ahead's acceleration [1].
    k_cruise
        Gain towards the cruising speed on a free road [1/s].
    k_close
        Extra free-road speed per metre of excess gap behind a CAV [1/s].
    time_gap_s
        Time gap added to the desired gap [s].
    hv_time_gap_s
        Extra time gap when the vehicle ahead is human-driven [s].
    """

    k_gap: float = 0.45
    k_speed: float = 1.1
    k_accel: float = 0.3
    k_cruise: float = 0.6
    k_close: float = 0.15
    time_gap_s: float = 0.0
    hv_time_gap_s: float = 0.0

    def __post_init__(self) -> None:
        check_positive(self, "k_gap", "k_speed", "k_cruise")
        check_non_negative(self, "k_accel", "time_gap_s", "hv_time_gap_s", "k_close")


@dataclass(frozen=True)
class SwarmSettings:
    """When the swarm decides to overtake, and how it tracks its plan.

    The swarm's other thresholds (re-forming, passing alone, replanning, giving up, lane ends)
    are constants beside the code that uses them, each with the reason for its value: no
    scenario set them, and no test ran them at another value (issue 51).

    Attributes
    ----------
    decide
        How the swarm chooses what to do about a slow vehicle ahead: ``"weigh"`` predicts
        following, waiting for it to leave the lane, a lane pass and the cells over
        ``horizon_s`` and takes the best for everyone on the road
        (:mod:`sumo_swarm.core.swarming.arbiter`); ``"paper"`` is the paper's trigger: the
        cells (or a lane pass that beats them) on a slow vehicle, after the earlier rules for
        one that catches up or keeps right. On the paper scene both start the same cells.
    horizon_s
        The horizon the candidates are predicted over [s].
    others_weight
        A metre lost by another vehicle against a metre gained by a CAV in the weighing [1]:
        1 counts every vehicle alike.
    trigger_speed_ratio
        An overtake is considered when the leader is held below this share of the cruising speed
        [1].
    trigger_after_s
        ...for this long, by a slower vehicle ahead [s].
    detect_range_m
        The slower vehicle must be within this gap of the leader [m].
    start_after_s
        No overtaking decision before this simulated time [s].
    accelerating_mps2
        A vehicle ahead accelerating harder than this is getting up to speed, not a target [m/s²].
    catching_up_ahead_m
        A slow vehicle is only catching up (not a target) when it and every vehicle this far ahead
        of it in its lane want at least the trigger speed [m].
    control_interval_s
        MPC re-solve period; in between the solved inputs are held [s].
    hand_over_in_lane
        Hand the pass over to the cruise once all CAVs are settled in one lane faster than the
        plan's pace.
    lane_pass
        Pass in a faster lane as a unit where that beats the cell plan.
    lane_pass_stall_s
        A lane pass with no CAV getting out of the target's lane or past it for this long hands
        over to the cell plan [s].
    lane_pass_beats
        What a free lane must beat by min_speed_gain_mps for a lane pass: the plan's pace ("cells")
        or the lower of that and the cruise ("free").
    min_speed_gain_mps
        Overtake only when the swarm's speed cap exceeds the target's speed by at least this [m/s].
    interval_rule
        Behaving interval: long enough that a one-row move never needs a speed above the cap
        ("drivable"), or always planner.behaving_interval_s ("fixed").
    cooldown_s
        No new overtaking decision for this long after a give-up [s].
    pass_singly_s
        After a give-up for no progress or stranded CAVs, the leader too passes on its own for this
        long (0: the platoon follows) [s].
    keep_right_wait_s
        A target that keeps right with a free lane on its right is waited for up to this long
        before the swarm starts (0: never) [s].
    keep_right_middle
        A keep-right target with a lane on its left: pass on its left with its right lane closed
        ("left"), wait for it ("wait"), or start at once on either side ("go").
    keep_right_move_s
        A keep-right driver is expected to move over this long after the lane to its right is free
        for it [s].
    keep_right_due
        Read when the keep-right move is due from SUMO's driver state, and judge the followers
        there as SUMO will.
    keep_right_wish
        While the target wants to keep right and its right lane opens within keep_right_soon_s,
        that lane is closed to the cell plan.
    keep_right_soon_s
        How soon the target's right lane must open for keep_right_wish to close it [s].
    keep_right_ahead_s
        Nothing slower may be within this time ahead in the target's right lane for it to be judged
        free [s].
    in_lane_tolerance_m
        A CAV is in a lane when within this of its centre [m].
    """

    decide: Literal["weigh", "paper"] = "weigh"
    horizon_s: float = 20.0
    others_weight: float = 1.0
    trigger_speed_ratio: float = 0.95
    trigger_after_s: float = 2.0
    detect_range_m: float = 60.0
    start_after_s: float = 1.0
    accelerating_mps2: float = 0.5
    catching_up_ahead_m: float = 300.0
    control_interval_s: float = 0.18
    hand_over_in_lane: bool = True
    lane_pass: bool = True
    lane_pass_stall_s: float = 15.0
    lane_pass_beats: Literal["cells", "free"] = "free"
    min_speed_gain_mps: float = 2.0
    interval_rule: Literal["drivable", "fixed"] = "drivable"
    cooldown_s: float = 15.0
    pass_singly_s: float = 60.0
    keep_right_wait_s: float = 10.0
    keep_right_middle: Literal["left", "wait", "go"] = "left"
    keep_right_move_s: float = 5.0
    keep_right_due: bool = True
    keep_right_wish: bool = True
    keep_right_soon_s: float = 10.0
    keep_right_ahead_s: float = 4.0
    in_lane_tolerance_m: float = 0.3

    def __post_init__(self) -> None:
        check_positive(
            self, "horizon_s", "trigger_speed_ratio", "detect_range_m", "control_interval_s",
        )  # fmt: skip
        check_non_negative(
            self, "others_weight", "trigger_after_s", "start_after_s", "min_speed_gain_mps",
            "cooldown_s", "pass_singly_s", "in_lane_tolerance_m",
            "keep_right_wait_s", "accelerating_mps2", "catching_up_ahead_m", "keep_right_move_s",
            "keep_right_soon_s", "keep_right_ahead_s", "lane_pass_stall_s",
        )  # fmt: skip


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

    Attributes
    ----------
    b_safe_mps2
        The hardest an HV may be made to brake by a CAV entering ahead of it [m/s²].
    planner_share
        Share of b_safe the planner's margins allow [1].
    target_b_mps2
        The swarm regroups ahead of the target no closer than where the target would brake harder
        than this [m/s²].
    block_decel_share
        A blocker entering at a faster lane's speed slows that lane at this share of b_safe [1].
    entry_speed_gain_mps
        A CAV entering a faster lane speeds up by up to this much above the grid's speed first
        [m/s].
    margin_rule
        Entry margins from the HV's car-following model ("model") or from a time headway
        ("headway").
    predictor
        How HVs are predicted: by their car-following model, or at constant speed.
    prediction_dt_s
        Time step of the HV prediction [s] (SUMO's step where that is longer).
    """

    b_safe_mps2: float = 2.0
    planner_share: float = 0.7
    target_b_mps2: float = 0.3
    block_decel_share: float = 0.7
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

    ``grouping = "many"``: CAVs that meet in a lane, held by a slow vehicle, form a platoon: a
    CAV joins a platoon whose CAV it follows (or leads) in its lane within ``join_gap_m``
    (bumper to bumper), where a slow vehicle holds the front CAV of that column; two platoons
    that meet so merge; none grows beyond ``max_size`` CAVs. A platoon for which nothing the
    CAVs do together pays parts, and SUMO drives its CAVs alone (see the fleet module). A
    cruising platoon whose CAVs are
    strung out with a gap beyond ``split_gap_m`` between two of them (along the road, any lane)
    splits there. CAVs group only where they drive on the session's route frame, in a lane
    that goes on for ``exit_reach_s`` at their speed (at least ``exit_reach_min_m``), with
    their own exit no nearer; a CAV whose exit comes that near leaves its platoon (its route's
    lane changes are SUMO's, its speed our CACC's), as one on a ramp or in an acceleration lane
    stays out of them until it may join.
    Membership is reviewed every ``review_every_s``; a platoon in the middle of an overtake
    keeps its CAVs (but loses one that approaches its exit).

    ``grouping = "one"``: every CAV of the run is one swarm, from the start, whatever it meets
    (the paper's scene: scenarios/paper.toml sets it).

    Attributes
    ----------
    grouping
        Form platoons of nearby CAVs as they meet ("many") or one platoon of every CAV ("one").
    join_gap_m
        A CAV within this gap of a platoon in its lane joins it [m].
    max_size
        Largest platoon [CAVs].
    split_gap_m
        A platoon splits where a gap between its CAVs grows beyond this [m].
    review_every_s
        How often the platoons are reviewed (joins, splits) [s].
    exit_reach_s
        A CAV whose route leaves the platoon's leaves the platoon this long before the parting
        point [s].
    exit_reach_min_m
        ...and at least this far before it [m].
    manoeuvre_clearance_m
        A swarm starts an overtake only where no other swarm's manoeuvre is within this distance
        [m].
    """

    grouping: Literal["many", "one"] = "many"
    join_gap_m: float = 60.0
    max_size: int = 12
    split_gap_m: float = 150.0
    review_every_s: float = 1.0
    exit_reach_s: float = 25.0
    exit_reach_min_m: float = 600.0
    manoeuvre_clearance_m: float = 100.0

    def __post_init__(self) -> None:
        check_positive(
            self, "join_gap_m", "split_gap_m", "review_every_s", "exit_reach_s",
            "exit_reach_min_m",
        )  # fmt: skip
        require_number("manoeuvre_clearance_m", self.manoeuvre_clearance_m, ge=0.0)
        check_fields(self, "max_size", ge=1)
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

    Attributes
    ----------
    length_m
        Length of the main road [m].
    lanes
        Through lanes (the swarm needs 2 or more) [lanes].
    speed_limit_mps
        Speed limit of the main road [m/s].
    lane_width_m
        Lane width [m].
    on_ramp_positions_m
        Where each on-ramp's acceleration lane begins, from the upstream end, in order [m].
    on_ramp_demands_vph
        Demand of each on-ramp, one per position [veh/h].
    off_ramp_positions_m
        Where each off-ramp's deceleration lane ends, from the upstream end, in order [m].
    off_ramp_shares
        Share of the main-road traffic just upstream of each off-ramp that leaves there [1].
    accel_lane_m
        Length of an on-ramp's acceleration lane [m].
    decel_lane_m
        Length of an off-ramp's deceleration lane [m].
    ramp_length_m
        Length of each ramp's own edge [m].
    ramp_speed_limit_mps
        Speed limit on the ramps [m/s].
    main_demand_vph_per_lane
        Demand at the upstream end, per through lane [veh/h].
    cav_share
        Share of CAVs in every demand [1].
    truck_share
        Share of trucks in every demand [1].
    truck_desired_speed_mps
        Trucks' desired speed, times SUMO's speed factor [m/s].
    truck_max_speed_mps
        Trucks' maximum speed [m/s].
    speed_dev
        SUMO's speed-factor spread of cars and trucks [1].
    arrivals
        Departures at random (exponential headways, "poisson") or evenly spaced ("uniform").
    """

    length_m: float = 6000.0
    lanes: int = 3
    speed_limit_mps: float = 33.33
    lane_width_m: float = 3.5
    on_ramp_positions_m: tuple[float, ...] = field(
        default=(), metadata={"range": "each > 0, on the road"}
    )
    on_ramp_demands_vph: tuple[float, ...] = field(default=(), metadata={"range": "each >= 0"})
    off_ramp_positions_m: tuple[float, ...] = field(
        default=(), metadata={"range": "each > 0, on the road"}
    )
    off_ramp_shares: tuple[float, ...] = field(default=(), metadata={"range": "each >= 0 and <= 1"})
    accel_lane_m: float = 250.0
    decel_lane_m: float = 250.0
    ramp_length_m: float = 300.0
    ramp_speed_limit_mps: float = 22.22
    main_demand_vph_per_lane: float = 1500.0
    cav_share: float = 0.2
    truck_share: float = 0.15
    truck_desired_speed_mps: float = 23.0
    truck_max_speed_mps: float = 25.0
    speed_dev: float = 0.1
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
        """The network file, relative to the scenario file; where there is none, the built-in
        network of that file name (so a copy of the paper's scenario runs wherever it is)."""
        beside = (self.path.parent / self.simulation.network).resolve()
        if beside.is_file():
            return beside
        built_in = BUILT_IN_NETWORKS / Path(self.simulation.network).name
        return built_in if built_in.is_file() else beside

    @property
    def cell_length_m(self) -> float:
        return self.cell.resolve(self.cav)


def union_members(tp: Any) -> tuple[Any, ...]:
    """The alternatives of a type hint: ``(A, B)`` for ``A | B`` or ``Optional``; ``(tp,)``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return (tp,)


# The networks installed with the package (sumo_swarm/data), by file name.
BUILT_IN_NETWORKS = Path(__file__).resolve().parent / "data"


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
        raise ConfigError(unknown_name("key", unknown[0], sorted(fields), prefix=dotted))
    kwargs = {name: _convert(value, hints[name], f"{dotted}{name}") for name, value in data.items()}
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None
    except TypeError as exc:  # a required field is missing
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """The tables of a TOML file; ConfigError naming the file when missing, unreadable, bad."""
    from sumo_swarm.userfiles import read_user_text

    text = read_user_text(path, what)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: malformed TOML: {exc}") from None
    # An empty file (or only comments) is a file not yet written, or the wrong one: run with
    # every default instead, it would pass silently for the file the user meant.
    if not data:
        raise ConfigError(f"{path}: the {what} is empty (no keys, no tables)")
    return data


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
            if "base" in unknown:
                raise ConfigError(
                    "this is a sweep file, not a scenario: run it with 'sumo-swarm batch FILE "
                    "--out DIR'"
                )
            raise ConfigError(unknown_name("section", unknown[0], sorted(SECTIONS), shown="[{}]"))
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
        if not scenario.network_path.exists():  # anything else: refused by parse_xml
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
    edge = sc.simulation.route_edges[0]
    lengths = {}
    for e in root.iter("edge"):
        if e.get("id") == edge:
            for lane in e.findall("lane"):
                try:
                    lengths[int(lane.get("index", "0"))] = float(lane.get("length", "nan"))
                except ValueError:
                    raise ConfigError(
                        f"{path}: simulation.network: {net}: malformed lane of edge '{edge}'"
                    ) from None
    try:
        check_scene_geometry(sc, edge, lengths)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def check_scene_geometry(sc: Scenario, edge: str, lane_lengths_m: dict[int, float]) -> None:
    """The scene's vehicles where SUMO can put them at t = 0, checked before any is made (a
    count of 10**11 CAVs would otherwise fill the memory first): every one on its lane of the
    first route edge ``edge`` (``lane_lengths_m``: lane index -> length [m]), front bumper not
    beyond its end, rear not before its start, and no two overlapping in a lane. ConfigError
    naming the key."""
    scene, cav, hv = sc.scene, sc.cav, sc.hv

    def length_of(lane: int) -> float:
        length_m = lane_lengths_m.get(lane, math.nan)
        return length_m if math.isfinite(length_m) else math.inf

    road = f"lane {scene.platoon_lane} of edge '{edge}'"
    lane_m = length_of(scene.platoon_lane)
    if cav.length_m > lane_m:
        raise ConfigError(
            f"cav.length_m = {cav.length_m:g}: a CAV longer than {road} ({lane_m:g} m)"
        )
    if scene.leader_front_m > lane_m:
        raise ConfigError(
            f"scene.leader_front_m = {scene.leader_front_m:g}: beyond the end of {road} "
            f"({lane_m:g} m), where the CAVs depart"
        )
    step_m = cav.length_m + scene.initial_gap_m
    platoon_m = cav.count * step_m - scene.initial_gap_m  # leader's front to last one's rear
    if platoon_m > scene.leader_front_m + 1e-9:
        fits = int((scene.leader_front_m + scene.initial_gap_m) // step_m)
        raise ConfigError(
            f"cav.count = {cav.count}: {cav.count} CAVs {cav.length_m:g} m long, "
            f"{scene.initial_gap_m:g} m apart need {platoon_m:g} m behind scene.leader_front_m "
            f"= {scene.leader_front_m:g} m; {fits} fit"
        )
    # (lane, rear, front, key) of everything placed: the platoon as one block
    placed = [(scene.platoon_lane, scene.leader_front_m - platoon_m, scene.leader_front_m,
               "scene.leader_front_m", "the CAVs")]  # fmt: skip
    if not any(h.role == "target" for h in scene.hv):  # build_scene puts one ahead of the CAVs
        front = scene.leader_front_m + scene.initial_gap_m + hv.length_m
        if front > lane_m:
            raise ConfigError(
                f"scene.leader_front_m = {scene.leader_front_m:g}: the slow HV placed ahead "
                f"of the CAVs would be beyond the end of {road} ({lane_m:g} m)"
            )
        placed.append((scene.platoon_lane, front - hv.length_m, front, "scene.leader_front_m",
                       "the slow HV ahead"))  # fmt: skip
    for h in scene.hv:
        key, length_m = f"scene.hv '{h.id}'.front_m", h.length_m or hv.length_m
        end_m = length_of(h.lane)
        if h.front_m > end_m:
            raise ConfigError(
                f"{key} = {h.front_m:g}: beyond the end of lane {h.lane} of edge '{edge}' "
                f"({end_m:g} m)"
            )
        if h.front_m - length_m < 0.0:
            raise ConfigError(
                f"{key} = {h.front_m:g}: its rear ({length_m:g} m long) would be before the "
                f"start of edge '{edge}'"
            )
        placed.append((h.lane, h.front_m - length_m, h.front_m, key, f"'{h.id}'"))
    placed.sort(key=lambda p: (p[0], -p[2]))
    for ahead, behind in itertools.pairwise(placed):
        if ahead[0] == behind[0] and behind[2] > ahead[1] + 1e-9:
            later = behind if behind[3] != "scene.leader_front_m" else ahead
            raise ConfigError(
                f"{later[3]}: {behind[4]} ({behind[1]:g}-{behind[2]:g} m) and {ahead[4]} "
                f"({ahead[1]:g}-{ahead[2]:g} m) overlap in lane {ahead[0]}"
            )


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
