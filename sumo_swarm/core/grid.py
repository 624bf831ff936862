"""Moving grid of cells around the platoon and the target vehicle (paper Sec. II-B-1).

Pure module: no SUMO import. Rows count forward from the rear of the grid (row 0 holds the
tail CAV), columns are lanes (column ``q`` is SUMO lane ``q``, 0 = rightmost). The grid moves
along the road at ``speed_mps``, so a vehicle driving at the grid speed stays in its cells.

Vehicle positions follow :mod:`sumo_swarm.core.model`: ``s_m`` is the front bumper, the cell of a
vehicle is the cell containing its *centre*.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from sumo_swarm.checks import check_fields, require_number
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.errors import ConfigError

Cell = tuple[int, int]  # (row, column)


# The most rows a grid may add ahead of the target (15 km of 15 m cells): every row is cells
# the planner's model holds at every step.
MAX_ROWS_AHEAD = 1000


@dataclass(frozen=True)
class GridSettings:
    """How the road is cut into cells and how much room an HV claims.

    Attributes
    ----------
    cell_length_m
        Cell length [m]: CAV length plus the desired safety distance (paper Step 2).
    rows_ahead
        Rows added in front of the target HV's footprint, room for the whole swarm to regroup
        [rows]; ``None`` = one row per CAV.
    headway_s
        Minimum time headway an HV keeps behind a CAV that cut in ahead of it [s].
    gap_behind_m
        Minimum gap between a CAV's front bumper and the rear of an HV ahead of it [m].
    cav_length_m
        CAV length [m], used to turn the gaps above into cell-centre bounds.
    lateral_overlap_m
        An HV whose centre is farther than this from its lane centre also blocks the
        neighbouring lane on that side [m].
    hv_sweep
        An HV also claims, at both ends of a behaving interval, the cells it drives through
        during it (its footprint and hard margin, a sample per row it moves relative to the
        grid). The paper checks cells at the interval ends only: an HV 20 m/s faster than the
        grid moves 4 rows per 3 s interval and "jumped" over a CAV the plan had put in its lane
        (a 5-lane motorway: a cut-in 175 m ahead of a 35 m/s HV that the lateral guard refused,
        then a drift, failed replans and a platoon braked to 11 m/s). Off by default (the
        paper's check): on users' roads at 900-1800 veh/h/lane the plans then found no way
        into lanes 15 m/s faster than the truck, and over 15 runs (5 roads x 3 seeds) the swarm
        averaged 1.36x cacc's CAV speed against 1.45x without it; the lateral guard stays the
        net for what the cells miss.
    """

    cell_length_m: float = 15.0
    rows_ahead: int | None = None
    headway_s: float = 1.2
    gap_behind_m: float = 5.0
    cav_length_m: float = 5.0
    lateral_overlap_m: float = 0.6
    hv_sweep: bool = False

    def __post_init__(self) -> None:
        _require_positive("cell_length_m", self.cell_length_m)
        _require_positive("cav_length_m", self.cav_length_m)
        _require_non_negative("headway_s", self.headway_s)
        _require_non_negative("gap_behind_m", self.gap_behind_m)
        _require_non_negative("lateral_overlap_m", self.lateral_overlap_m)
        check_fields(self, "rows_ahead", ge=0, le=MAX_ROWS_AHEAD, integer=True)


def _require_positive(name: str, value: float) -> None:
    require_number(f"GridSettings.{name}", value, gt=0.0)


def _require_non_negative(name: str, value: float) -> None:
    require_number(f"GridSettings.{name}", value, ge=0.0)


def _is_number(value: object) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


@dataclass(frozen=True)
class MovingGrid:
    """A grid of ``n_rows`` x ``road.n_lanes`` cells moving along the road.

    ``origin_s_m`` is the rear edge of row 0 at time ``t0_s`` [m along the route]; the
    grid moves forward at ``speed_mps``.
    """

    origin_s_m: float
    t0_s: float
    speed_mps: float
    cell_length_m: float
    n_rows: int
    road: RoadSection

    @property
    def n_cols(self) -> int:
        return self.road.n_lanes

    def origin_at(self, t_s: float) -> float:
        """Rear edge of row 0 at time ``t_s`` [m]."""
        return self.origin_s_m + self.speed_mps * (t_s - self.t0_s)

    def row_of(self, s_m: float, t_s: float) -> int:
        """Row containing the longitudinal position ``s_m`` at ``t_s`` (may be out of range)."""
        return math.floor((s_m - self.origin_at(t_s)) / self.cell_length_m)

    def cell_centre_s(self, row: int, t_s: float) -> float:
        """Longitudinal position of the centre of ``row`` at ``t_s`` [m]."""
        return self.origin_at(t_s) + (row + 0.5) * self.cell_length_m

    def column_y(self, col: int) -> float:
        """Lateral position of the centre of column ``col`` [m] (from the centre of lane 0)."""
        return self.road.lane_centre_y(col)

    def contains(self, row: int, col: int) -> bool:
        return 0 <= row < self.n_rows and 0 <= col < self.n_cols


class HvPredictor(Protocol):
    """Predicts a human-driven vehicle's state at a future time."""

    def predict(self, hv: VehicleState, now_s: float, t_s: float) -> VehicleState: ...


class ConstantSpeedPredictor:
    """Keeps speed and lane: ``s(t) = s(now) + v * (t - now)``."""

    def predict(self, hv: VehicleState, now_s: float, t_s: float) -> VehicleState:
        return dataclasses.replace(hv, s_m=hv.s_m + hv.speed_mps * (t_s - now_s))


def cav_cell(grid: MovingGrid, cav: VehicleState, road: RoadSection, t_s: float) -> Cell:
    """Cell ``(row, col)`` of a vehicle at ``t_s``: the row and the lane of its centre."""
    row = grid.row_of(cav.centre_s_m, t_s)
    col = road.road_lane_of(cav)  # a CAV still beside the road: the lane it merges into
    return row, col


def hv_blocked_rows(
    grid: MovingGrid,
    hv: VehicleState,
    t_s: float,
    settings: GridSettings,
    front_margin_m: float | None = None,
) -> range:
    """Rows (unclipped, may lie outside the grid) whose centres an HV claims at ``t_s``.

    A CAV centred at ``c`` is too close if its front is within ``gap_behind_m`` of the HV's rear,
    or its rear within ``front_margin_m`` of the HV's front (default: the paper's constant
    headway, ``headway_s * hv.speed_mps``); both bounds are open.
    """
    if front_margin_m is None:
        front_margin_m = settings.headway_s * max(hv.speed_mps, 0.0)
    half_cav = 0.5 * settings.cav_length_m
    low_s = hv.rear_s_m - settings.gap_behind_m - half_cav
    high_s = hv.s_m + min(front_margin_m, 1e4) + half_cav
    origin = grid.origin_at(t_s)
    length = grid.cell_length_m
    # Centre of row r is origin + (r + 0.5) * length; keep rows with low_s < centre < high_s.
    first = math.floor((low_s - origin) / length - 0.5) + 1
    last = math.ceil((high_s - origin) / length - 0.5) - 1
    return range(first, last + 1)


def hv_columns(grid: MovingGrid, hv: VehicleState, settings: GridSettings) -> tuple[int, ...]:
    """Columns an HV claims: its own, plus the neighbour it leans into by > lateral_overlap_m."""
    road = grid.road
    y = road.y_of(hv.lane, hv.lat_m)
    col = road.road_lane_of_y(y)  # beside the road: it claims the lane it merges into
    offset = y - grid.column_y(col)
    cols = [col]
    if offset > settings.lateral_overlap_m and col + 1 < grid.n_cols:
        cols.append(col + 1)
    elif offset < -settings.lateral_overlap_m and col - 1 >= 0:
        cols.append(col - 1)
    return tuple(cols)


def hv_blocked_cells(
    grid: MovingGrid,
    hv: VehicleState,
    t_s: float,
    settings: GridSettings,
    front_margin_m: float | None = None,
) -> frozenset[Cell]:
    """In-grid cells where a CAV centre would violate the HV's safety margins at ``t_s``."""
    rows = hv_blocked_rows(grid, hv, t_s, settings, front_margin_m)
    in_grid_rows = range(max(rows.start, 0), min(rows.stop, grid.n_rows))
    return frozenset((r, c) for c in hv_columns(grid, hv, settings) for r in in_grid_rows)


def build_grid(
    cavs: Sequence[VehicleState],
    target: VehicleState,
    road: RoadSection,
    t_s: float,
    speed_mps: float,
    settings: GridSettings,
    target_front_margin_m: float | None = None,
) -> MovingGrid:
    """Grid the road around the platoon and the target HV (paper Steps 1-4).

    Row 0 is centred on the tail CAV (the CAV farthest back). The grid reaches the front of
    the target HV's footprint (the rows it claims, see :func:`hv_blocked_rows`) or the front
    CAV, whichever is farther, plus ``rows_ahead`` rows (default one per CAV) for the swarm
    to regroup in ahead of the target.
    """
    if not cavs:
        raise ConfigError("build_grid needs at least one CAV")
    if not _is_number(speed_mps):
        raise ConfigError(f"build_grid: speed_mps must be a finite number, got {speed_mps!r}")
    length = settings.cell_length_m
    tail_centre = min(cav.centre_s_m for cav in cavs)
    origin = tail_centre - 0.5 * length
    # Provisional grid to measure rows; n_rows does not affect row arithmetic.
    probe = MovingGrid(origin, t_s, speed_mps, length, 1, road)
    front_cav_row = max(probe.row_of(cav.centre_s_m, t_s) for cav in cavs)
    target_rows = hv_blocked_rows(probe, target, t_s, settings, target_front_margin_m)
    # With zero margins a short HV may cover no cell centre; then its own row is its footprint.
    target_top_row = target_rows[-1] if target_rows else probe.row_of(target.centre_s_m, t_s)
    rows_ahead = len(cavs) if settings.rows_ahead is None else settings.rows_ahead
    n_rows = max(front_cav_row, target_top_row) + 1 + rows_ahead
    return MovingGrid(origin, t_s, speed_mps, length, n_rows, road)
