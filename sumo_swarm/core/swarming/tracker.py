"""Tracking the references with the MPCs (paper Section II-D), one pair per CAV (pure).

The longitudinal MPC works in time, the lateral one in space; both are re-solved every
``[swarm] control_interval_s`` (rounded to whole SUMO steps) and their input sequences
applied in between (zero-order hold on the MPC's own step). :meth:`Tracker.command` returns
what the CAV should do this step; the controller applies the guards, then
:meth:`Tracker.commit` takes the heading it ends the step with.

A SUMO step longer than the MPC's own step (``dt_s``, 0.1 s) is driven on the MPC's clock:
the inputs solved for each of its steps within the SUMO step are applied in turn to the
kinematic model (eqs. 33-35), and SUMO is handed the step's whole lateral move, the mean
acceleration and the heading at its end. Holding the first input for the whole step instead
turned the CAV 10 MPC steps' worth at 1 s: the front CAV of the paper scene's variants swung
across the lane line and back every step, and the CAVs behind it braked to a standstill.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.tracking import (
    STEADY,
    LateralMpc,
    LateralSettings,
    LongitudinalMpc,
    LongitudinalSettings,
)
from sumo_swarm.core.trajectory import Reference


@dataclass(frozen=True)
class TrackCommand:
    """What the tracker asks of one CAV for one SUMO step."""

    accel_mps2: float  # longitudinal acceleration (mean over the step)
    dlat_m: float  # lateral move over the step
    lat_error_m: float  # lateral distance from the reference now
    phi_end_rad: float = 0.0  # heading at the end of the step, moving as commanded


class Tracker:
    """Per-CAV MPCs, warm-started; solved every ``interval_steps`` calls."""

    def __init__(
        self,
        lon: LongitudinalSettings,
        lat: LateralSettings,
        interval_steps: int,
    ) -> None:
        self.lon, self.lat = lon, lat
        self.interval_steps = interval_steps
        self._lon: dict[str, LongitudinalMpc] = {}
        self._lat: dict[str, LateralMpc] = {}
        self.phi: dict[str, float] = {}
        self._inputs: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        self._calls = 0
        self.solve_ms: list[float] = []
        self._kappa: tuple[tuple[float, float], np.ndarray] | None = None

    def _curvature(self, curvature_1pm: float) -> np.ndarray:
        """The road curvature over the lateral horizon, read-only, made again only when the
        curvature changes (every CAV asks at every solve)."""
        key = (curvature_1pm, math.copysign(1.0, curvature_1pm))  # -0.0 is not 0.0 here
        if self._kappa is None or self._kappa[0] != key:
            kappa = np.full(self.lat.horizon, curvature_1pm)
            kappa.flags.writeable = False
            self._kappa = (key, kappa)
        return self._kappa[1]

    def add(self, vid: str) -> None:
        """Track CAV ``vid`` from now on. Its two MPCs are set up at its first solve
        (:meth:`_mpcs`): most CAVs of a corridor's platoons only ever cruise, and setting up
        OSQP for each CAV that joined one took a tenth of the swarm's time there."""
        self.phi.setdefault(vid, 0.0)

    def _mpcs(self, vid: str) -> tuple[LongitudinalMpc, LateralMpc]:
        lon = self._lon.get(vid)
        if lon is None:
            lon = self._lon[vid] = LongitudinalMpc(self.lon)
            self._lat[vid] = LateralMpc(self.lat)
        return lon, self._lat[vid]

    def reset(self) -> None:
        """Forget the solved inputs (a new plan: solve at the next call)."""
        self._inputs = {}

    def tick(self) -> bool:
        """Advance one SUMO step; True when the MPCs are due for a solve."""
        due = self._calls % self.interval_steps == 0
        self._calls += 1
        return due

    def command(
        self,
        t_s: float,
        ego: VehicleState,
        ref: Reference,
        road: RoadSection,
        dt_s: float,
        solve: bool,
    ) -> TrackCommand:
        vid = ego.vehicle_id
        self.add(vid)
        centre = ego.centre_s_m
        y = road.y_of(ego.lane, ego.lat_m)
        if solve or vid not in self._inputs:
            s_ref, v_ref = ref.targets_time(t_s, self.lon.dt_s, self.lon.horizon)
            lon, lat = self._mpcs(vid)
            res = lon.solve(centre, ego.speed_mps, s_ref, v_ref)
            ds = max(ego.speed_mps, 1.0) * self.lat.dt_s
            y_ref, dy_ref = ref.targets_space(centre, ds, self.lat.horizon)
            kappa = self._curvature(road.curvature_1pm)
            lres = lat.solve(y, self.phi[vid], y_ref, np.arctan(dy_ref), kappa, ds)
            if lres.status == STEADY:
                self.phi[vid] = 0.0  # centred and straight on: straight ahead
            self._inputs[vid] = (t_s, res.inputs, lres.inputs)
            self.solve_ms.append(res.solve_ms + lres.solve_ms)
        t_solved, accels, deltas = self._inputs[vid]
        # The lateral move of this SUMO step from the kinematic model (eqs. 33-35), on the
        # MPC's clock: one sub-step per MPC step within the SUMO step (one at the paper's).
        n = max(1, round(dt_s / self.lat.dt_s))
        h = dt_s / n
        v, phi, dlat, dv = ego.speed_mps, self.phi[vid], 0.0, 0.0
        for k in range(n):
            t = t_s - t_solved + k * h
            accel = float(accels[min(int(t / self.lon.dt_s + 1e-9), len(accels) - 1)])
            delta = float(deltas[min(int(t / self.lat.dt_s + 1e-9), len(deltas) - 1)])
            speed = max(v + dv, 0.0)
            dlat += speed * h * math.sin(phi)
            phi += speed * h * (math.tan(delta) / self.lat.wheelbase_m - road.curvature_1pm)
            dv += accel * h
        return TrackCommand(dv / dt_s, dlat, y - ref.y_at_s(centre), phi)

    def commit(
        self, ego: VehicleState, cmd: TrackCommand, held: bool, road: RoadSection, dt_s: float
    ) -> None:
        """The heading at the end of the step (:meth:`command` integrated it); a move held by
        the guard stops turning towards the lane."""
        vid = ego.vehicle_id
        self.phi[vid] = 0.0 if held else cmd.phi_end_rad

    def straighten(self, vids: Mapping[str, object] | list[str]) -> None:
        for vid in vids:
            self.phi[vid] = 0.0
