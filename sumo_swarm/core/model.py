"""Plain value objects shared by every stage of the control loop (no SUMO import).

Coordinates
-----------
``s_m``
    Distance of the vehicle's *front bumper* along its route [m] (SUMO's convention for
    ``lanePosition``, accumulated over the route's edges).
``lane``
    Lane index, 0 = rightmost lane (SUMO's convention). Grid columns use the same index.
``lat_m``
    Lateral offset of the vehicle centre from the centre of its lane [m], left positive.
``y_m``
    Lateral position of the vehicle centre measured from the centre of lane 0 [m], left
    positive: ``road.lane_centre_y(lane) + lat_m``. Planner and trajectory use this.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


# Not frozen, for speed: one is made for every vehicle at every step (and many more by the
# planner's predictions), and a frozen dataclass takes five times as long to make (each field
# set through object.__setattr__). Treat it as a value all the same: never assign to a field
# (caches such as neighbours.snapshot_of tell tables apart by the states they hold);
# dataclasses.replace makes a changed copy. Hashable by value, as a frozen one is.
@dataclass(slots=True, unsafe_hash=True)
class VehicleState:
    """Snapshot of one vehicle at one instant."""

    vehicle_id: str
    s_m: float  # front bumper along the route [m]
    lane: int  # 0 = rightmost
    lat_m: float  # centre offset from the lane centre [m], left positive
    speed_mps: float
    length_m: float
    accel_mps2: float = 0.0
    is_cav: bool = False
    width_m: float = 1.8

    @property
    def rear_s_m(self) -> float:
        """Position of the rear bumper along the route [m]."""
        return self.s_m - self.length_m

    @property
    def centre_s_m(self) -> float:
        """Position of the vehicle centre along the route [m]."""
        return self.s_m - 0.5 * self.length_m


@dataclass(frozen=True, slots=True)
class RoadSection:
    """Cross-section of the road where the swarm drives.

    ``lane_widths_m[q]`` is the width of lane ``q`` (0 = rightmost) [m]. ``curvature_1pm``
    is the curvature of the road's reference line at the swarm [1/m], left turns positive.
    """

    lane_widths_m: tuple[float, ...]
    curvature_1pm: float = 0.0
    # Lane centres from lane 0's centre [m], computed once (y_of runs for every vehicle pair).
    _centres: tuple[float, ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        w = self.lane_widths_m
        centres = tuple(sum(w[:q]) + 0.5 * w[q] - 0.5 * w[0] for q in range(len(w)))
        object.__setattr__(self, "_centres", centres)

    @property
    def n_lanes(self) -> int:
        return len(self.lane_widths_m)

    def lane_centre_y(self, lane: int) -> float:
        """Lateral position of the centre of ``lane`` measured from the centre of lane 0 [m].

        Lanes outside the section (a vehicle still on an edge with more lanes) are placed by
        extending the outermost lane widths.
        """
        centres = self._centres
        if 0 <= lane < len(centres):
            return centres[lane]
        widths = self.lane_widths_m
        if lane < 0:
            return lane * widths[0]
        return centres[-1] + (lane - len(centres) + 1) * widths[-1]

    def y_of(self, lane: int, lat_m: float) -> float:
        """Lateral position [m], from lane 0's centre, of a point ``lat_m`` off a lane centre."""
        centres = self._centres
        if 0 <= lane < len(centres):
            return centres[lane] + lat_m
        return self.lane_centre_y(lane) + lat_m

    def ys_of(self, lanes: list[int], lats_m: list[float]) -> list[float]:
        """:meth:`y_of` of each ``(lane, lat)`` pair (the same numbers, one call for a whole
        step's vehicles)."""
        centres = self._centres
        n = len(centres)
        return [
            centres[lane] + lat if 0 <= lane < n else self.lane_centre_y(lane) + lat
            for lane, lat in zip(lanes, lats_m, strict=True)
        ]

    def nearest_lane(self, lane: int) -> int:
        """The lane of this section nearest to lane index ``lane``, which may lie beside it (a
        lane counted on an edge with more lanes: an acceleration lane is -1)."""
        return min(max(lane, 0), self.n_lanes - 1)

    def lane_width_m(self, lane: int) -> float:
        """Width [m] of lane index ``lane``; beside the road, the outermost lane's on that side
        (as :meth:`lane_centre_y` and :meth:`lane_of_y` extend the bands)."""
        return self.lane_widths_m[self.nearest_lane(lane)]

    def road_lane_of(self, vehicle: VehicleState) -> int:
        """The lane of this section ``vehicle`` is in (:meth:`lane_of`), or, beside it (in an
        acceleration lane), the one it merges into."""
        return self.nearest_lane(self.lane_of(vehicle))

    def road_lane_of_y(self, y_m: float) -> int:
        """:meth:`road_lane_of` of the lateral position ``y_m``."""
        return self.nearest_lane(self.lane_of_y(y_m))

    def lane_of(self, vehicle: VehicleState) -> int:
        """Lane index whose band holds ``vehicle``'s centre (a vehicle half-way through a lane
        change counts in the lane it is mostly in, whatever SUMO's lane index says); beside
        the road, the index of the lane it is in there (an acceleration lane is -1)."""
        return self.lane_of_y(self.y_of(vehicle.lane, vehicle.lat_m))

    def lane_of_y(self, y_m: float) -> int:
        """Lane index whose band contains the lateral position ``y_m``; beside the road, the
        bands go on at the outermost lanes' widths (-1 is the band right of lane 0, as
        :meth:`lane_centre_y` places it). :meth:`nearest_lane` of it is a lane of the road."""
        widths = self.lane_widths_m
        edge = -0.5 * widths[0]
        if y_m < edge:
            return -math.ceil((edge - y_m) / widths[0])
        for lane, width in enumerate(widths):
            edge += width
            if y_m < edge:
                return lane
        return self.n_lanes + math.floor((y_m - edge) / widths[-1])
