"""Planning problems to and from plain JSON values (benchmark fixtures, debugging).

A :class:`PlanningProblem` is pure cell arithmetic, so its fields are all a solver needs: a
problem the swarm built in a run can be stored, reloaded and solved again by any planner.
Cells become ``[row, col]`` lists, per-step cell sets sorted lists.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

from sumo_swarm.core.grid import Cell
from sumo_swarm.core.planner.problem import Blocker, PlannerWeights, PlanningProblem
from sumo_swarm.errors import ConfigError


def _cells(cells: frozenset[Cell]) -> list[list[int]]:
    return [list(cell) for cell in sorted(cells)]


def _cell_sets(value: Any) -> tuple[frozenset[Cell], ...]:
    return tuple(frozenset((int(r), int(c)) for r, c in cells) for cells in value)


def problem_to_dict(problem: PlanningProblem) -> dict[str, Any]:
    """Every field of ``problem`` as JSON-ready lists, numbers and strings."""
    return {
        "n_rows": problem.n_rows,
        "n_cols": problem.n_cols,
        "n_steps": problem.n_steps,
        "cav_ids": list(problem.cav_ids),
        "start_cells": [list(c) for c in problem.start_cells],
        "blocked": [_cells(b) for b in problem.blocked],
        "goal_rows": list(problem.goal_rows),
        "regroup_lane": problem.regroup_lane,
        "weights": asdict(problem.weights),
        "target_form": problem.target_form,
        "delta_mode": problem.delta_mode,
        "blockers": [{**asdict(b), "cell": list(b.cell)} for b in problem.blockers],
        "hv_ids": list(problem.hv_ids),
        "target_id": problem.target_id,
        "target_col": problem.target_col,
        "t0_s": problem.t0_s,
        "behaving_interval_s": problem.behaving_interval_s,
        "entry_blocked": [_cells(b) for b in problem.entry_blocked],
        "exempt_moves": sorted([k, list(a), list(b)] for k, a, b in problem.exempt_moves),
        "hv_tracks": [[col, [round(r, 6) for r in rows]] for col, rows in problem.hv_tracks],
        "start_rows": [round(r, 6) for r in problem.start_rows],
        "stay_ok": _cells(problem.stay_ok),
        "stay_on": [_cells(cells) for cells in problem.stay_on],
        "idle_holds": [_cells(cells) for cells in problem.idle_holds],
    }


def problem_from_dict(data: Mapping[str, Any]) -> PlanningProblem:
    """The inverse of :func:`problem_to_dict`; ``ConfigError`` on a missing or bad field."""
    try:
        return PlanningProblem(
            n_rows=int(data["n_rows"]),
            n_cols=int(data["n_cols"]),
            n_steps=int(data["n_steps"]),
            cav_ids=tuple(data["cav_ids"]),
            start_cells=tuple((int(r), int(c)) for r, c in data["start_cells"]),
            blocked=_cell_sets(data["blocked"]),
            goal_rows=tuple(int(g) for g in data["goal_rows"]),
            regroup_lane=int(data["regroup_lane"]),
            weights=PlannerWeights(**data["weights"]),
            target_form=data["target_form"],
            delta_mode=data["delta_mode"],
            blockers=tuple(
                Blocker(
                    int(b["cav_index"]),
                    b["cav_id"],
                    b["hv_id"],
                    (int(b["cell"][0]), int(b["cell"][1])),
                    int(b["hold_steps"]),
                )
                for b in data["blockers"]
            ),
            hv_ids=tuple(data["hv_ids"]),
            target_id=data["target_id"],
            target_col=data["target_col"],
            t0_s=float(data["t0_s"]),
            behaving_interval_s=float(data["behaving_interval_s"]),
            entry_blocked=_cell_sets(data["entry_blocked"]),
            exempt_moves=frozenset(
                (int(k), (int(a[0]), int(a[1])), (int(b[0]), int(b[1])))
                for k, a, b in data["exempt_moves"]
            ),
            hv_tracks=tuple(
                (int(col), tuple(float(r) for r in rows)) for col, rows in data["hv_tracks"]
            ),
            start_rows=tuple(float(r) for r in data["start_rows"]),
            stay_ok=frozenset((int(r), int(c)) for r, c in data["stay_ok"]),
            stay_on=_cell_sets(data.get("stay_on", [])),
            idle_holds=_cell_sets(data.get("idle_holds", [])),
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ConfigError(f"planning problem: bad or missing field ({exc!r})") from None
