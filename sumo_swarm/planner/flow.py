"""The cell MIP as a 0-1 program on a time-expanded flow graph, shared by every backend.

Why a flow: every CAV pays the same costs for the same cells and moves, so which CAV is in
a cell does not change the objective. With at most one CAV per cell (eq. (14)) the CAVs'
paths form a unit-capacity flow in the time-expanded graph (nodes = (step, cell), edges =
stay or one row/column move, eqs. (8)-(13)), and such a flow splits back into per-CAV paths
in exactly one way: a node carries one CAV, which leaves by its one used edge. So one
Boolean per (step, move) replaces one per (CAV, step, cell), the CAV-permutation symmetry
disappears, and the relaxation without the delta coupling is a min-cost flow (integral).
Only blockers (eqs. (16)-(17)) name a CAV; they fix the edge leaving that CAV's start cell.

Variables (all 0-1): ``e`` per edge; ``d`` per step whose delta is not fixed by reachability;
``q`` per lateral edge leaving a non-impeded node while delta is open (``q = e and not d``: the
move is free); ``z`` per non-impeded node off the regroup lane while delta is open
(``z = y and d``: the regroup cost is waived). A node's occupancy ``y`` is the sum of its
in-edges (no variable), so node costs sit on the in-edges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from sumo_swarm.grid import Cell
from sumo_swarm.planner.problem import PlanningProblem, move_allowed, target_cost

# Constraint kinds: "eq" sum == rhs, "le" sum <= rhs, "ge" sum >= rhs.
Constraint = tuple[str, list[int], list[int], int]


@dataclass
class FlowModel:
    """Backend-neutral 0-1 program; variable ``v`` is edge ``v`` for ``v < n_edges``."""

    problem: PlanningProblem
    nodes: list[tuple[int, Cell]] = field(default_factory=list)
    node_index: dict[tuple[int, Cell], int] = field(default_factory=dict)
    edges: list[tuple[int, int]] = field(default_factory=list)  # (from node, to node)
    out_edges: list[list[int]] = field(default_factory=list)
    in_edges: list[list[int]] = field(default_factory=list)
    delta_var: dict[int, int] = field(default_factory=dict)  # step -> d variable
    delta_fixed: dict[int, int] = field(default_factory=dict)  # step -> 0/1
    n_vars: int = 0
    objective: dict[int, int] = field(default_factory=dict)  # var -> integer coefficient
    constraints: list[Constraint] = field(default_factory=list)
    fixed: dict[int, int] = field(default_factory=dict)  # var -> value
    scale: int = 1  # objective in problem units = integer objective / scale
    infeasible_reason: str | None = None
    aux: list[tuple[str, int, int]] = field(default_factory=list)  # (kind "q"/"z", var, of)

    def new_var(self) -> int:
        self.n_vars += 1
        return self.n_vars - 1


def objective_scale(problem: PlanningProblem) -> int:
    """Smallest power of ten making every weight integral (capped at 10**6, then rounded)."""
    weights = problem.weights
    values = (weights.w_tar, weights.w_lon, weights.w_lat)
    for exponent in range(7):
        scale = 10**exponent
        if all(abs(v * scale - round(v * scale)) < 1e-9 for v in values):
            return scale
    return 10**6


def _neighbours(cell: Cell, n_rows: int, n_cols: int) -> list[Cell]:
    row, col = cell
    out = [cell]
    for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        r, c = row + dr, col + dc
        if 0 <= r < n_rows and 0 <= c < n_cols:
            out.append((r, c))
    return out


def reachable_cells(problem: PlanningProblem) -> list[set[Cell]] | str:
    """Cells some CAV can be in at each step and still stay feasible to the horizon.

    Forward from the start cells through cells no HV claims, then backward keeping only cells
    with a successor. Returns a reason string if a step is left with fewer cells than CAVs.
    """
    n_rows, n_cols, n_steps = problem.n_rows, problem.n_cols, problem.n_steps
    layers: list[set[Cell]] = [set(problem.start_cells)]
    for k in range(1, n_steps):
        layer = {
            nxt
            for cell in layers[-1]
            for nxt in _neighbours(cell, n_rows, n_cols)
            if move_allowed(problem, k - 1, cell, nxt)
        }
        layers.append(layer)
    for k in range(n_steps - 2, -1, -1):
        after = layers[k + 1]
        layers[k] = {
            cell
            for cell in layers[k]
            if any(
                nxt in after and move_allowed(problem, k, cell, nxt)
                for nxt in _neighbours(cell, n_rows, n_cols)
            )
        }
    if layers[0] != set(problem.start_cells):
        stuck = sorted(set(problem.start_cells) - layers[0])
        return f"a CAV has no way through the HV-blocked cells (from {stuck})"
    for k, layer in enumerate(layers[1:], start=1):
        if len(layer) < problem.n_cavs:
            return f"fewer free reachable cells than CAVs at step {k}"
    return layers


def _cav_earliest_free_step(problem: PlanningProblem, layers: list[set[Cell]]) -> int:
    """First step at which every CAV could, on its own, be ahead of the target (else N)."""
    worst = 0
    for start in set(problem.start_cells):
        frontier = {start}
        k = 0
        while k < problem.n_steps and not any(row >= problem.goal_rows[k] for row, _ in frontier):
            k += 1
            if k == problem.n_steps:
                break
            frontier = {
                nxt
                for cell in frontier
                for nxt in _neighbours(cell, problem.n_rows, problem.n_cols)
                if nxt in layers[k]
            }
        worst = max(worst, k)
    return worst


def build_flow_model(problem: PlanningProblem) -> FlowModel:
    """Build the 0-1 program of ``problem`` (see the module docstring)."""
    model = FlowModel(problem)
    model.scale = objective_scale(problem)
    layers = reachable_cells(problem)
    if isinstance(layers, str):
        model.infeasible_reason = layers
        return model
    _add_nodes_and_edges(model, layers)
    _add_flow_constraints(model)
    _add_swap_constraints(model)
    _add_blockers(model)
    if model.infeasible_reason is None:
        _add_delta_and_costs(model, layers)
    return model


def _add_nodes_and_edges(model: FlowModel, layers: list[set[Cell]]) -> None:
    problem = model.problem
    for k, layer in enumerate(layers):
        for cell in sorted(layer):
            model.node_index[(k, cell)] = len(model.nodes)
            model.nodes.append((k, cell))
            model.out_edges.append([])
            model.in_edges.append([])
    for node, (k, cell) in enumerate(model.nodes):
        if k + 1 == problem.n_steps:
            continue
        for nxt in _neighbours(cell, problem.n_rows, problem.n_cols):
            other = model.node_index.get((k + 1, nxt))
            if other is None or not move_allowed(problem, k, cell, nxt):
                continue
            edge = len(model.edges)
            model.edges.append((node, other))
            model.out_edges[node].append(edge)
            model.in_edges[other].append(edge)
    model.n_vars = len(model.edges)


def _add_flow_constraints(model: FlowModel) -> None:
    problem = model.problem
    supply: dict[Cell, int] = {}
    for cell in problem.start_cells:
        supply[cell] = supply.get(cell, 0) + 1
    for node, (k, cell) in enumerate(model.nodes):
        outs = model.out_edges[node]
        if k == 0:
            model.constraints.append(("eq", outs, [1] * len(outs), supply[cell]))
            continue
        ins = model.in_edges[node]
        model.constraints.append(("le", ins, [1] * len(ins), 1))
        if outs:
            model.constraints.append(("eq", ins + outs, [1] * len(ins) + [-1] * len(outs), 0))


def _add_swap_constraints(model: FlowModel) -> None:
    """No two CAVs trade cells in one step: e(a->b) + e(b->a) <= 1."""
    edge_of = {model.edges[j]: j for j in range(len(model.edges))}
    for j, (a, b) in enumerate(model.edges):
        if a == b:
            continue
        ka, cell_a = model.nodes[a]
        _, cell_b = model.nodes[b]
        if cell_a >= cell_b:  # visit each unordered pair once
            continue
        back_from = model.node_index.get((ka, cell_b))
        back_to = model.node_index.get((ka + 1, cell_a))
        if back_from is None or back_to is None:
            continue
        back = edge_of.get((back_from, back_to))
        if back is not None:
            model.constraints.append(("le", [j, back], [1, 1], 1))


def _add_blockers(model: FlowModel) -> None:
    problem = model.problem
    for blocker in problem.blockers:
        path = [problem.start_cells[blocker.cav_index]] + [blocker.cell] * blocker.hold_steps
        for k in range(len(path) - 1):
            edge = _find_edge(model, k, path[k], path[k + 1])
            if edge is None:
                model.infeasible_reason = (
                    f"blocker {blocker.cav_id} cannot be in {path[k + 1]} at step {k + 1}"
                )
                return
            model.fixed[edge] = 1


def _find_edge(model: FlowModel, k: int, src: Cell, dst: Cell) -> int | None:
    node = model.node_index.get((k, src))
    other = model.node_index.get((k + 1, dst))
    if node is None or other is None:
        return None
    for edge in model.out_edges[node]:
        if model.edges[edge][1] == other:
            return edge
    return None


def _add_delta_and_costs(model: FlowModel, layers: list[set[Cell]]) -> None:
    problem = model.problem
    scale = model.scale
    w_lon2 = round(2 * problem.weights.w_lon * scale)
    w_lat = round(problem.weights.w_lat * scale)
    w_lat2 = 2 * w_lat
    lane = problem.regroup_lane
    goal = problem.goal_rows

    # Delta_k is 1 while a CAV is impeded: fixed to 1 before every CAV could be ahead of the
    # target, fixed to 0 when no reachable cell is behind it, a variable otherwise. With
    # delta_mode "cav" each CAV has its own delta, known from its cell: nothing to decide.
    per_cav = problem.delta_mode == "cav"
    if not per_cav:
        earliest_free = _cav_earliest_free_step(problem, layers)
        model.delta_fixed[0] = int(any(row < goal[0] for row, _ in problem.start_cells))
        for k in range(1, problem.n_steps):
            if k < earliest_free:
                model.delta_fixed[k] = 1
            elif not any(row < goal[k] for row, _ in layers[k]):
                model.delta_fixed[k] = 0
            else:
                model.delta_var[k] = model.new_var()

    impeded_by_step: dict[int, list[list[int]]] = {k: [] for k in model.delta_var}
    for node, (k, (row, col)) in enumerate(model.nodes):
        impeded = row < goal[k]
        delta_fixed = (1 if impeded else 0) if per_cav else model.delta_fixed.get(k)
        d = model.delta_var.get(k)
        if k >= 1:
            ins = model.in_edges[node]
            cost = round(target_cost(problem, row, k) * scale)
            regroup = w_lat * (lane - col) ** 2
            if impeded:
                if d is not None:
                    impeded_by_step[k].append(ins)
            elif regroup:
                if d is not None:
                    # Pay the regroup cost unless delta_k waives it: z = y and d.
                    z = model.new_var()
                    model.constraints.append(("le", [z, *ins], [1] + [-1] * len(ins), 0))
                    model.constraints.append(("le", [z, d], [1, -1], 0))
                    model.aux.append(("z", z, node))
                    cost += regroup
                    _add_cost(model, z, -regroup)
                elif delta_fixed == 0:
                    cost += regroup
            for edge in ins:
                _add_cost(model, edge, cost)
        if k + 1 == problem.n_steps:
            continue
        for edge in model.out_edges[node]:
            _, (next_row, next_col) = model.nodes[model.edges[edge][1]]
            if next_row != row:
                _add_cost(model, edge, w_lon2)
            elif next_col != col:
                if impeded or delta_fixed == 1:
                    _add_cost(model, edge, w_lat2)
                elif d is not None:
                    # Lateral moves cost only while delta_k = 1: q = e and not d is free.
                    q = model.new_var()
                    model.constraints.append(("le", [q, edge], [1, -1], 0))
                    model.constraints.append(("le", [q, d], [1, 1], 1))
                    model.aux.append(("q", q, edge))
                    _add_cost(model, edge, w_lat2)
                    _add_cost(model, q, -w_lat2)
    for k, node_ins in impeded_by_step.items():
        d = model.delta_var[k]
        for ins in node_ins:
            model.constraints.append(("le", [*ins, d], [1] * len(ins) + [-1], 0))
        flat = [edge for ins in node_ins for edge in ins]
        model.constraints.append(("le", [d, *flat], [1] + [-1] * len(flat), 0))


def _add_cost(model: FlowModel, var: int, coef: int) -> None:
    if coef:
        model.objective[var] = model.objective.get(var, 0) + coef


def hint_values(model: FlowModel, cells: Sequence[Sequence[Cell]]) -> dict[int, int]:
    """0-1 values of every variable for the paths ``cells`` (for solver hints).

    Edges missing from the model (the hint went through a now blocked cell) are skipped; the
    solver repairs the rest.
    """
    problem = model.problem
    values = dict.fromkeys(range(model.n_vars), 0)
    n_steps = min(problem.n_steps, min(len(path) for path in cells))
    occupied: set[int] = set()
    for path in cells:
        for k in range(n_steps - 1):
            edge = _find_edge(model, k, path[k], path[k + 1])
            if edge is not None:
                values[edge] = 1
                occupied.add(model.edges[edge][1])
    for k, d in model.delta_var.items():
        values[d] = int(any(path[k][0] < problem.goal_rows[k] for path in cells if k < len(path)))
    for kind, var, of in model.aux:
        if kind == "z":
            k = model.nodes[of][0]
            values[var] = int(of in occupied) & values[model.delta_var[k]]
        else:
            k = model.nodes[model.edges[of][0]][0]
            values[var] = values[of] & (1 - values[model.delta_var[k]])
    return values


def extract_paths(model: FlowModel, edge_values: Sequence[int]) -> tuple[tuple[Cell, ...], ...]:
    """Split a 0-1 flow into per-CAV paths (CAVs in problem order).

    From a start cell shared by several CAVs (step 0 only) a blocker takes its fixed edge and
    the others take the remaining edges, the frontmost CAV the frontmost destination.
    """
    problem = model.problem
    used_out: dict[int, list[int]] = {}
    for edge, value in enumerate(edge_values):
        if value:
            used_out.setdefault(model.edges[edge][0], []).append(edge)
    first_edge: dict[int, int] = {}
    blocker_first = {
        b.cav_index: _find_edge(model, 0, problem.start_cells[b.cav_index], b.cell)
        for b in problem.blockers
    }
    taken: set[int] = set()
    for i, edge in blocker_first.items():
        if edge is not None:
            first_edge[i] = edge
            taken.add(edge)
    order = sorted(range(problem.n_cavs), key=lambda i: (-problem.start_cells[i][0], i))
    for i in order:
        if i in first_edge:
            continue
        start = model.node_index[(0, problem.start_cells[i])]
        options = [e for e in used_out.get(start, []) if e not in taken]
        options.sort(key=lambda e: model.nodes[model.edges[e][1]][1], reverse=True)
        first_edge[i] = options[0]
        taken.add(options[0])
    paths = []
    for i in range(problem.n_cavs):
        path = [problem.start_cells[i]]
        edge = first_edge[i]
        while True:
            node = model.edges[edge][1]
            path.append(model.nodes[node][1])
            outs = used_out.get(node)
            if not outs:
                break
            edge = outs[0]
        paths.append(tuple(path))
    return tuple(paths)
