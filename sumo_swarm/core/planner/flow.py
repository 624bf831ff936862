"""The cell MIP as a 0-1 program on a time-expanded flow graph, shared by every backend.

Why a flow: every CAV pays the same costs for the same cells and moves, so which CAV is in
a cell does not change the objective. With at most one CAV per cell (eq. (14)) the CAVs'
paths form a unit-capacity flow in the time-expanded graph (nodes = (step, cell), edges =
stay or one row/column move, eqs. (8)-(13)), and such a flow splits back into per-CAV paths
in exactly one way: a node carries one CAV, which leaves by its one used edge. So one
Boolean per (step, move) replaces one per (CAV, step, cell), the CAV-permutation symmetry
disappears, and the relaxation without the delta coupling is a min-cost flow (integral).
Only blockers (eqs. (16)-(17)) name a CAV; they fix the edge leaving that CAV's start cell.

No swapping is not a constraint of the model: two CAVs trading cells ``a <-> b`` in one step
leave the same cells occupied as both staying, and staying never costs more (node costs sit on
the in-edges and are the same; a stay costs no move, and ``q`` of a stay is 0), so
:func:`uncross_swaps` replaces every swap of a solution by two stays at no extra cost. An
optimum of the model without the swap rows is thus an optimum with them, and the model keeps
the min-cost-flow structure the LP relaxation needs. Only a blocker's fixed move cannot be
uncrossed: its reverse edge is fixed to 0.

Variables (all 0-1): ``e`` per edge; ``d`` per step whose delta is not fixed by reachability;
``q`` per lateral edge leaving a non-impeded node while delta is open (``q = e and not d``: the
move is free); ``z`` per non-impeded node off the regroup lane while delta is open
(``z = y and d``: the regroup cost is waived). A node's occupancy ``y`` is the sum of its
in-edges (no variable), so node costs sit on the in-edges.

Everything is built with numpy arrays (nodes, edges, costs); the constraint rows are kept in
a few flat groups that each backend turns into its own form in one pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sumo_swarm.core.grid import Cell
from sumo_swarm.core.planner.problem import MOVES, PlanningProblem, cell_mask, move_masks

# Moves in the order the edges of a node are numbered: stay, row up, row down, column up/down.


@dataclass
class LinearRows:
    """Linear rows ``lo <= sum coefs * vars <= hi`` in compressed form (``start`` has n + 1)."""

    start: list[int] = field(default_factory=lambda: [0])
    vars: list[int] = field(default_factory=list)
    coefs: list[int] = field(default_factory=list)
    lo: list[int] = field(default_factory=list)
    hi: list[int] = field(default_factory=list)

    def add(self, variables: Sequence[int], coefs: Sequence[int], lo: int, hi: int) -> None:
        self.vars.extend(variables)
        self.coefs.extend(coefs)
        self.start.append(len(self.vars))
        self.lo.append(lo)
        self.hi.append(hi)

    def __len__(self) -> int:
        return len(self.lo)

    def row(self, i: int) -> tuple[list[int], list[int], int, int]:
        a, b = self.start[i], self.start[i + 1]
        return self.vars[a:b], self.coefs[a:b], self.lo[i], self.hi[i]


@dataclass
class FlowModel:
    """Backend-neutral 0-1 program; variable ``v`` is edge ``v`` for ``v < n_edges``.

    Constraint groups: ``linear`` rows; ``at_most_one`` sets of variables (sum <= 1);
    ``implies`` pairs ``(a, b)`` meaning ``a <= b``. ``lower``/``upper`` are the variables'
    bounds (fixings). ``objective`` holds one integer coefficient per variable.
    """

    problem: PlanningProblem
    scale: int = 1  # objective in problem units = integer objective / scale
    has_rows: bool = True  # False: built for the network search only (no rows, q or z)
    infeasible_reason: str | None = None
    n_nodes: int = 0
    node_k: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_row: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_col: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_id: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), np.int64))
    edge_src: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_dst: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_move: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    stay_edge: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # per node
    n_vars: int = 0
    delta_var: dict[int, int] = field(default_factory=dict)  # step -> d variable
    delta_fixed: dict[int, int] = field(default_factory=dict)  # step -> 0/1
    linear: LinearRows = field(default_factory=LinearRows)
    at_most_one: list[list[int]] = field(default_factory=list)
    implies: list[tuple[int, int]] = field(default_factory=list)
    lower: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    upper: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    objective: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    q_vars: list[tuple[int, int]] = field(default_factory=list)  # (q variable, its edge)
    z_vars: list[tuple[int, int]] = field(default_factory=list)  # (z variable, its node)
    out_edge: np.ndarray = field(default_factory=lambda: np.zeros((0, 5), np.int64))  # [node, move]
    in_edges: list[list[int]] = field(default_factory=list)  # per node
    # The objective split by where it is charged (integer units), for the network solver:
    # a node's cost (target, and the regroup cost where delta may be 0) and what a z refunds
    # of it when delta is 1 at its open step; an edge's move cost (lateral charged) and what a
    # q refunds of it when delta is 0 at its source's open step. ``impeded`` per node.
    node_cost: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_refund: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_cost: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_refund: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    impeded: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    # Pairs of opposite edges (a -> b, b -> a) of one step that cannot be uncrossed into two
    # stays (a stay is not allowed there): both may not be used (no swapping).
    swap_pairs: list[tuple[int, int]] = field(default_factory=list)

    @property
    def n_edges(self) -> int:
        return len(self.edge_src)

    def new_var(self) -> int:
        self.n_vars += 1
        return self.n_vars - 1

    def edge_between(self, k: int, src: Cell, dst: Cell) -> int | None:
        """The edge from ``src`` at step ``k`` to ``dst`` at step ``k + 1``, if it exists."""
        dr, dc = dst[0] - src[0], dst[1] - src[1]
        if (dr, dc) not in MOVES:
            return None
        a, b = self.node_at(k, src), self.node_at(k + 1, dst)
        if a is None or b is None:
            return None
        edge = int(self.out_edge[a, MOVES.index((dr, dc))])
        return None if edge < 0 else edge

    def node_at(self, k: int, cell: Cell) -> int | None:
        row, col = cell
        n_steps, n_rows, n_cols = self.node_id.shape
        if not (0 <= k < n_steps and 0 <= row < n_rows and 0 <= col < n_cols):
            return None
        node = int(self.node_id[k, row, col])
        return None if node < 0 else node


def objective_scale(problem: PlanningProblem) -> int:
    """Smallest power of ten making every weight integral (capped at 10**6, then rounded)."""
    weights = problem.weights
    values = (weights.w_tar, weights.w_lon, weights.w_lat)
    for exponent in range(7):
        scale = 10**exponent
        if all(abs(v * scale - round(v * scale)) < 1e-9 for v in values):
            return scale
    return 10**6


def _dilate(mask: np.ndarray) -> np.ndarray:
    """Cells reachable in one move (stay or one row/column) from ``mask`` (last two axes)."""
    out = mask.copy()
    out[..., 1:, :] |= mask[..., :-1, :]
    out[..., :-1, :] |= mask[..., 1:, :]
    out[..., :, 1:] |= mask[..., :, :-1]
    out[..., :, :-1] |= mask[..., :, 1:]
    return out


def _shift(mask: np.ndarray, dr: int, dc: int) -> np.ndarray:
    """``out[r + dr, c + dc] = mask[r, c]`` (cells moved off the grid are dropped)."""
    n_rows, n_cols = mask.shape
    out = np.zeros_like(mask)
    out[max(0, dr) : n_rows + min(0, dr), max(0, dc) : n_cols + min(0, dc)] = mask[
        max(0, -dr) : n_rows - max(0, dr), max(0, -dc) : n_cols - max(0, dc)
    ]
    return out


def reachable_mask(problem: PlanningProblem, masks: np.ndarray | None = None) -> np.ndarray | str:
    """``[k, row, col]``: a CAV can be there at step ``k`` and still stay feasible to the horizon.

    Forward from the start cells by the allowed moves (:func:`move_masks`: HV cells, entry
    margins, no passing within a lane), then backward keeping only cells with an allowed move
    into a kept cell. Returns a reason string if a start cell has no way on or a step is left
    with fewer cells than CAVs.
    """
    masks = move_masks(problem) if masks is None else masks
    n_steps, n_rows, n_cols = problem.n_steps, problem.n_rows, problem.n_cols
    reach = np.zeros((n_steps, n_rows, n_cols), dtype=bool)
    starts = np.array(problem.start_cells)
    reach[0, starts[:, 0], starts[:, 1]] = True
    for k in range(1, n_steps):
        for m, (dr, dc) in enumerate(MOVES):
            reach[k] |= _shift(reach[k - 1] & masks[m, k - 1], dr, dc)
    for k in range(n_steps - 2, -1, -1):
        onward = np.zeros((n_rows, n_cols), dtype=bool)
        for m, (dr, dc) in enumerate(MOVES):
            onward |= masks[m, k] & _shift(reach[k + 1], -dr, -dc)
        reach[k] &= onward
    stuck = [cell for cell in sorted(set(problem.start_cells)) if not reach[0][cell]]
    if stuck:
        return f"a CAV has no way through the HV-blocked cells (from {stuck})"
    counts = reach[1:].reshape(n_steps - 1, -1).sum(axis=1)
    short = np.flatnonzero(counts < problem.n_cavs)
    if len(short):
        return f"fewer free reachable cells than CAVs at step {int(short[0]) + 1}"
    return reach


def _earliest_free_step(problem: PlanningProblem, reach: np.ndarray) -> int:
    """First step at which every CAV could, on its own, be ahead of the target (else N)."""
    starts = sorted(set(problem.start_cells))
    n_steps = problem.n_steps
    rows = np.arange(problem.n_rows)[:, None]
    frontier = np.zeros((len(starts), problem.n_rows, problem.n_cols), dtype=bool)
    for i, (row, col) in enumerate(starts):
        frontier[i, row, col] = True
    first = np.full(len(starts), n_steps)
    for k in range(n_steps):
        if k:
            frontier = _dilate(frontier) & reach[k]
        ahead = (frontier & (rows >= problem.goal_rows[k])).any(axis=(1, 2))
        first = np.where((first == n_steps) & ahead, k, first)
        if (first < n_steps).all():
            break
    return int(first.max())


def build_flow_model(problem: PlanningProblem, rows: bool = True) -> FlowModel:
    """Build the 0-1 program of ``problem`` (see the module docstring).

    ``rows=False`` leaves out the constraint rows and the ``q``/``z`` variables (what a MIP
    solver needs): nodes, edges, bounds, deltas and the split costs are all the network search
    of :mod:`sumo_swarm.core.planner.network` reads, and they cost a third of the build.
    """
    model = FlowModel(problem)
    model.has_rows = rows
    model.scale = objective_scale(problem)
    masks = move_masks(problem)
    reach = reachable_mask(problem, masks)
    if isinstance(reach, str):
        model.infeasible_reason = reach
        return model
    _add_nodes_and_edges(model, reach, masks)
    model.lower = np.zeros(model.n_vars, np.int64)
    model.upper = np.ones(model.n_vars, np.int64)
    if rows:
        _add_flow_constraints(model)
    _add_swap_exclusions(model)
    _add_blockers(model)
    if model.infeasible_reason is None:
        _add_delta_and_costs(model, reach)
    return model


def _add_nodes_and_edges(model: FlowModel, reach: np.ndarray, masks: np.ndarray) -> None:
    n_steps, n_rows, n_cols = reach.shape
    flat = np.flatnonzero(reach.ravel())
    model.n_nodes = len(flat)
    model.node_k, rest = np.divmod(flat, n_rows * n_cols)
    model.node_row, model.node_col = np.divmod(rest, n_cols)
    node_id = np.full(reach.shape, -1, dtype=np.int64)
    node_id.ravel()[flat] = np.arange(len(flat))
    model.node_id = node_id
    # Pad the id array by one cell on every side so that moves off the grid read -1.
    padded = np.full((n_steps + 1, n_rows + 2, n_cols + 2), -1, dtype=np.int64)
    padded[:n_steps, 1:-1, 1:-1] = node_id
    k, r, c = model.node_k, model.node_row + 1, model.node_col + 1
    out_edge = np.full((model.n_nodes, len(MOVES)), -1, dtype=np.int64)
    targets = np.stack([padded[k + 1, r + dr, c + dc] for dr, dc in MOVES], axis=1)
    allowed = masks[:, model.node_k, model.node_row, model.node_col].T  # [node, move]
    exists = (targets >= 0) & allowed  # the last step's nodes read the padding row: no edges
    src, move = np.nonzero(exists)  # row-major: by source node, then move order
    out_edge[src, move] = np.arange(len(src))
    model.edge_src, model.edge_move = src, move
    model.edge_dst = targets[src, move]
    model.out_edge = out_edge
    model.stay_edge = out_edge[:, 0]
    model.n_vars = len(src)


def _add_flow_constraints(model: FlowModel) -> None:
    problem = model.problem
    supply: dict[Cell, int] = {}
    for cell in problem.start_cells:
        supply[cell] = supply.get(cell, 0) + 1
    in_order = np.argsort(model.edge_dst, kind="stable")
    in_start = np.searchsorted(model.edge_dst[in_order], np.arange(model.n_nodes + 1))
    out_start = np.searchsorted(model.edge_src, np.arange(model.n_nodes + 1))
    in_order, in_start, out_start = in_order.tolist(), in_start.tolist(), out_start.tolist()
    node_k, rows, cols = model.node_k.tolist(), model.node_row.tolist(), model.node_col.tolist()
    linear = model.linear
    for node in range(model.n_nodes):
        outs = range(out_start[node], out_start[node + 1])
        if node_k[node] == 0:
            n_cavs = supply[(rows[node], cols[node])]
            linear.add(outs, [1] * len(outs), n_cavs, n_cavs)
            continue
        ins = in_order[in_start[node] : in_start[node + 1]]
        if len(ins) > 1:
            model.at_most_one.append(ins)
        if outs:
            linear.add([*ins, *outs], [1] * len(ins) + [-1] * len(outs), 0, 0)
    model.in_edges = [in_order[in_start[n] : in_start[n + 1]] for n in range(model.n_nodes)]


def _add_swap_exclusions(model: FlowModel) -> None:
    """No swapping where :func:`uncross_swaps` could not replace a swap by two stays."""
    lateral_or_row = np.flatnonzero(model.edge_move != 0)
    src, dst = model.edge_src[lateral_or_row], model.edge_dst[lateral_or_row]
    k = model.node_k[src]
    # The reverse move of each edge: its destination's cell at step k back to its source's.
    reverse_move = np.array([1, 2, 1, 4, 3])[model.edge_move[lateral_or_row]]
    back_src = model.node_id[k, model.node_row[dst], model.node_col[dst]]
    back = np.where(back_src >= 0, model.out_edge[np.maximum(back_src, 0), reverse_move], -1)
    # The reverse edge must end in this edge's source cell, which it does by construction.
    for edge, rev, a, b in zip(
        lateral_or_row.tolist(), back.tolist(), src.tolist(), back_src.tolist(), strict=True
    ):
        if rev <= edge:  # each pair once (and no reverse edge: nothing to exclude)
            continue
        if model.stay_edge[a] < 0 or model.stay_edge[b] < 0:
            model.swap_pairs.append((edge, rev))
            if model.has_rows:
                model.at_most_one.append([edge, rev])


def _add_blockers(model: FlowModel) -> None:
    problem = model.problem
    for blocker in problem.blockers:
        path = [problem.start_cells[blocker.cav_index]] + [blocker.cell] * blocker.hold_steps
        for k in range(len(path) - 1):
            edge = model.edge_between(k, path[k], path[k + 1])
            if edge is None:
                model.infeasible_reason = (
                    f"blocker {blocker.cav_id} cannot be in {path[k + 1]} at step {k + 1}"
                )
                return
            model.lower[edge] = 1
            # A fixed move cannot be uncrossed, so the CAV it would swap with may not come back.
            back = model.edge_between(k, path[k + 1], path[k]) if path[k] != path[k + 1] else None
            if back is not None:
                model.upper[back] = 0


def _add_delta_and_costs(model: FlowModel, reach: np.ndarray) -> None:
    problem = model.problem
    scale = model.scale
    weights = problem.weights
    w_lon2 = round(2 * weights.w_lon * scale)
    w_lat = round(weights.w_lat * scale)
    w_lat2 = 2 * w_lat
    goal = np.asarray(problem.goal_rows)
    n_steps = problem.n_steps

    # Delta_k is 1 while a CAV is impeded: fixed to 1 before every CAV could be ahead of the
    # target, fixed to 0 when no reachable cell is behind it, a variable otherwise. With
    # delta_mode "cav" each CAV has its own delta, known from its cell: nothing to decide.
    per_cav = problem.delta_mode == "cav"
    step_delta = np.full(n_steps, -1)  # 0/1 fixed, -1 open (a variable)
    if not per_cav:
        earliest_free = _earliest_free_step(problem, reach)
        model.delta_fixed[0] = int(any(row < goal[0] for row, _ in problem.start_cells))
        behind_any = (reach & (np.arange(problem.n_rows)[None, :, None] < goal[:, None, None])).any(
            axis=(1, 2)
        )
        for k in range(1, n_steps):
            if k < earliest_free:
                model.delta_fixed[k] = 1
            elif not behind_any[k]:
                model.delta_fixed[k] = 0
            else:
                model.delta_var[k] = model.new_var()
        for k, value in model.delta_fixed.items():
            step_delta[k] = value

    k_of, row_of, col_of = model.node_k, model.node_row, model.node_col
    impeded = row_of < goal[k_of]
    behind = np.maximum(goal[k_of] - row_of, 0)
    if problem.target_form == "paper":
        target = np.where(behind > 0, round(weights.w_tar * scale), 0)
    else:
        target = np.round(weights.w_tar * behind * scale).astype(np.int64)
    regroup = w_lat * (problem.regroup_lane - col_of) ** 2
    node_delta = np.where(impeded, 1, 0) if per_cav else step_delta[k_of]
    # Node cost (charged on its in-edges): target at steps >= 1; the regroup cost where no CAV
    # is impeded for sure, or (with a z variable) where delta is open.
    pays_regroup = (k_of >= 1) & ~impeded & (regroup > 0) & (node_delta != 1)
    node_cost = np.where(k_of >= 1, target, 0) + np.where(pays_regroup, regroup, 0)
    if problem.idle_holds:  # w_lat per step in a cell of an idle hold, whatever delta
        mask = cell_mask(problem.idle_holds, (n_steps, problem.n_rows, problem.n_cols))
        node_cost = node_cost + np.where((k_of >= 1) & mask[k_of, row_of, col_of], w_lat, 0)

    src, dst, move = model.edge_src, model.edge_dst, model.edge_move
    lateral = move >= 3
    src_paid = impeded[src] | (node_delta[src] == 1)
    edge_cost = node_cost[dst] + np.where((move == 1) | (move == 2), w_lon2, 0)
    edge_cost = edge_cost + np.where(lateral & (src_paid | (node_delta[src] == -1)), w_lat2, 0)

    # What a q (lateral move out of a non-impeded node at an open step, free while delta is 0)
    # and a z (regroup cost of a non-impeded node at an open step, waived while delta is 1)
    # give back.
    open_nodes = (k_of >= 1) & (node_delta == -1)
    refund_edges = lateral & ~src_paid & (node_delta[src] == -1)
    refund_nodes = open_nodes & ~impeded & (regroup > 0)
    model.edge_refund = np.where(refund_edges, w_lat2, 0).astype(np.int64)
    model.node_refund = np.where(refund_nodes, regroup, 0).astype(np.int64)
    new_costs: list[tuple[int, int]] = []
    in_edges = model.in_edges
    if model.delta_var and model.has_rows:
        # q = e and not d: a lateral move out of a non-impeded node is free while delta_k = 0.
        for edge in np.flatnonzero(refund_edges).tolist():
            d = model.delta_var[int(k_of[src[edge]])]
            q = model.new_var()
            model.implies.append((q, edge))
            model.at_most_one.append([q, d])
            model.q_vars.append((q, edge))
            new_costs.append((q, -w_lat2))
        # z = y and d: the regroup cost of a non-impeded node is waived while delta_k = 1.
        for node in np.flatnonzero(refund_nodes).tolist():
            d = model.delta_var[int(k_of[node])]
            z = model.new_var()
            ins = in_edges[node]
            if len(ins) == 1:
                model.implies.append((z, ins[0]))
            else:
                model.linear.add([z, *ins], [1] + [-1] * len(ins), -len(ins), 0)
            model.implies.append((z, d))
            model.z_vars.append((z, node))
            # The node pays the regroup cost through its in-edges (node_cost); z gives it back.
            new_costs.append((z, -int(regroup[node])))
        # y_n <= d for every impeded node, and d <= the sum of the impeded y at step k.
        impeded_open = np.flatnonzero(open_nodes & impeded)
        by_step: dict[int, list[int]] = {k: [] for k in model.delta_var}
        for node in impeded_open.tolist():
            k = int(k_of[node])
            d = model.delta_var[k]
            ins = in_edges[node]
            if len(ins) == 1:
                model.implies.append((ins[0], d))
            else:
                model.linear.add([*ins, d], [1] * len(ins) + [-1], -len(ins), 0)
            by_step[k].extend(ins)
        for k, flat in by_step.items():
            d = model.delta_var[k]
            model.linear.add([d, *flat], [1] + [-1] * len(flat), -len(flat), 0)
    model.lower = np.concatenate([model.lower, np.zeros(model.n_vars - len(model.lower), int)])
    model.upper = np.concatenate([model.upper, np.ones(model.n_vars - len(model.upper), int)])
    objective = np.zeros(model.n_vars, np.int64)
    objective[: model.n_edges] = edge_cost
    for var, coef in new_costs:
        objective[var] += coef
    model.objective = objective
    model.impeded = impeded
    model.node_cost = node_cost.astype(np.int64)
    model.edge_cost = (edge_cost - node_cost[dst]).astype(np.int64)


def hint_values(model: FlowModel, cells: Sequence[Sequence[Cell]]) -> list[int]:
    """0-1 value of every variable for the paths ``cells`` (a solver hint).

    Edges missing from the model (the hint went through a now blocked cell) are left at 0;
    the solver repairs the rest.
    """
    problem = model.problem
    values = [0] * model.n_vars
    n_steps = min(problem.n_steps, min(len(path) for path in cells))
    occupied: set[int] = set()
    for path in cells:
        for k in range(n_steps - 1):
            edge = model.edge_between(k, path[k], path[k + 1])
            if edge is not None:
                values[edge] = 1
                occupied.add(int(model.edge_dst[edge]))
    for k, d in model.delta_var.items():
        values[d] = int(any(path[k][0] < problem.goal_rows[k] for path in cells if k < len(path)))
    for z, node in model.z_vars:
        values[z] = int(node in occupied) & values[model.delta_var[int(model.node_k[node])]]
    for q, edge in model.q_vars:
        k = int(model.node_k[model.edge_src[edge]])
        values[q] = values[edge] & (1 - values[model.delta_var[k]])
    return values


def uncross_swaps(model: FlowModel, edge_values: Sequence[int]) -> tuple[list[int], int]:
    """Replace every pair of used edges ``a -> b``, ``b -> a`` of one step by two stays.

    Returns the new edge values and the number of swaps removed. The cells occupied at every
    step stay the same, so the cost does not rise (see the module docstring).
    """
    values = list(edge_values)
    used = [e for e, v in enumerate(values) if v and model.edge_move[e] != 0]
    swaps = 0
    for edge in used:
        a, b = int(model.edge_src[edge]), int(model.edge_dst[edge])
        k = int(model.node_k[a])
        cell_a = (int(model.node_row[a]), int(model.node_col[a]))
        cell_b = (int(model.node_row[b]), int(model.node_col[b]))
        back = model.edge_between(k, cell_b, cell_a)
        if back is None or not values[edge] or not values[back]:
            continue
        if model.stay_edge[a] < 0 or model.stay_edge[model.edge_src[back]] < 0:
            continue  # excluded by the model (swap_pairs); left for the validator to report
        values[edge] = values[back] = 0
        values[int(model.stay_edge[a])] = 1
        values[int(model.stay_edge[model.edge_src[back]])] = 1
        swaps += 1
    return values, swaps


def extract_paths(model: FlowModel, edge_values: Sequence[int]) -> tuple[tuple[Cell, ...], ...]:
    """Split a 0-1 flow into per-CAV paths (CAVs in problem order).

    From a start cell shared by several CAVs (step 0 only) a blocker takes its fixed edge and
    the others take the remaining edges, the frontmost CAV the frontmost destination.
    """
    problem = model.problem
    used_out: dict[int, list[int]] = {}
    for edge, value in enumerate(edge_values):
        if value:
            used_out.setdefault(int(model.edge_src[edge]), []).append(edge)
    cell_of = list(zip(model.node_row.tolist(), model.node_col.tolist(), strict=True))
    first_edge: dict[int, int] = {}
    taken: set[int] = set()
    for blocker in problem.blockers:
        edge = model.edge_between(0, problem.start_cells[blocker.cav_index], blocker.cell)
        if edge is not None:
            first_edge[blocker.cav_index] = edge
            taken.add(edge)
    order = sorted(range(problem.n_cavs), key=lambda i: (-problem.start_cells[i][0], i))
    for i in order:
        if i in first_edge:
            continue
        start = model.node_at(0, problem.start_cells[i])
        options = [e for e in used_out.get(start, []) if e not in taken]
        options.sort(key=lambda e: cell_of[model.edge_dst[e]], reverse=True)
        first_edge[i] = options[0]
        taken.add(options[0])
    paths = []
    for i in range(problem.n_cavs):
        path = [problem.start_cells[i]]
        edge = first_edge[i]
        while True:
            node = int(model.edge_dst[edge])
            path.append(cell_of[node])
            outs = used_out.get(node)
            if not outs:
                break
            edge = outs[0]
        paths.append(tuple(path))
    return tuple(paths)
