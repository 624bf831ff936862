"""Exact solution of the flow model by branch and bound over the paper's delta, on min-cost flows.

Why: the flow model of :mod:`sumo_swarm.core.planner.flow` is a min-cost flow except for the
per-step delta (eq. (5): 1 while some CAV is impeded) and the few swap exclusions. With every
delta fixed it *is* a min-cost flow, which OR-Tools' network simplex solves in about a
millisecond, where CP-SAT's LP search takes 50-300 ms on the swarm's 12-CAV problems and runs
out of time on the ones with many open deltas.

The network: per model node an in- and an out-node joined by a node arc of capacity 1 (at most
one CAV per cell, eq. (14)) that carries the node's cost; per model edge an arc from the source's
out-node to the destination's in-node carrying the move's cost; the last step's out-nodes feed a
sink. Start cells supply their CAVs at their out-nodes. A blocker's fixed edge (eqs. (16)-(17))
is taken out of the network and its unit moved into the supplies. Costs that depend on an open
delta come as two parallel arcs of which one is switched on (capacity 1) at a time.

Branch and bound, each open step ``k`` in one of three states:

* ``0``: no CAV impeded at ``k`` (impeded nodes switched off), regroup cost charged at ``k``,
  lateral moves out of ``k`` free;
* ``1``: regroup cost waived at ``k``, lateral moves out of ``k`` charged, and some CAV impeded
  at ``k``: the impeded nodes of ``k`` are entered and left through a hub with one unit
  forced through it. A unit may leave the hub by another node than it entered (a relaxation);
  such a flow is branched on that node being used or not;
* open: the cheaper cost of each arc and impeded nodes allowed (a relaxation of both).

Every flow is a plan of the model: its true cost (delta from the CAVs it keeps impeded) is an
upper bound, its flow cost a lower bound of its branch. Branches are explored best bound first
until none can beat the best plan: that plan is then optimal for the model (the same optimum
the MIP solvers prove). A swap that cannot be uncrossed (``FlowModel.swap_pairs``) is branched
on as well (one edge or the other switched off).
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass, field

import numpy as np

from sumo_swarm.core.planner.flow import FlowModel

# Branch states of an open delta step.
OPEN, ZERO, ONE = -1, 0, 1


@dataclass
class NetworkResult:
    """Outcome of :func:`solve_network`: status ``optimal``, ``feasible`` (limit reached with a
    plan), ``infeasible`` or ``limit`` (limit reached without one); integer objective units."""

    status: str
    edge_values: list[int] | None = None
    objective: int | None = None
    bound: int | None = None
    branches: int = 0
    message: str = ""


@dataclass(order=True)
class _Branch:
    bound: int
    order: int
    states: dict[int, int] = field(compare=False)
    forced: frozenset[int] = field(compare=False, default=frozenset())  # nodes that must be used
    banned: frozenset[int] = field(compare=False, default=frozenset())  # nodes switched off
    cut: frozenset[int] = field(compare=False, default=frozenset())  # edges switched off


class _Network:
    """The flow model as arrays of arcs for OR-Tools' min-cost flow (built once per model)."""

    def __init__(self, model: FlowModel) -> None:
        self.model = model
        n = model.n_nodes
        k_of = model.node_k
        self.n_steps = model.problem.n_steps
        self.open_steps = sorted(model.delta_var)
        self.sink = 2 * n
        tails: list[np.ndarray] = []
        heads: list[np.ndarray] = []
        costs: list[np.ndarray] = []
        # Node arcs (steps >= 1): variant "charged" for every node, "refunded" where a z exists.
        inner = np.flatnonzero(k_of >= 1)
        refundable = inner[model.node_refund[inner] > 0]
        self.node_arc = np.full(n, -1, np.int64)
        self.node_arc_refund = np.full(n, -1, np.int64)
        first = 0
        for nodes, cost, slot in (
            (inner, model.node_cost[inner], self.node_arc),
            (refundable, model.node_cost[refundable] - model.node_refund[refundable],
             self.node_arc_refund),
        ):  # fmt: skip
            tails.append(nodes)
            heads.append(nodes + n)
            costs.append(cost)
            slot[nodes] = np.arange(first, first + len(nodes))
            first += len(nodes)
        # Edge arcs: out-node of the source to the in-node of the destination (a step-0 node's
        # in- and out-node are the same: its out-node, where the supply is).
        src, dst = model.edge_src, model.edge_dst
        head = np.where(k_of[dst] >= 1, dst, dst + n)
        refund_edges = np.flatnonzero(model.edge_refund > 0)
        self.edge_arc = np.arange(first, first + len(src))
        first += len(src)
        self.edge_arc_refund = np.full(len(src), -1, np.int64)
        self.edge_arc_refund[refund_edges] = np.arange(first, first + len(refund_edges))
        first += len(refund_edges)
        tails += [src + n, src[refund_edges] + n]
        heads += [head, head[refund_edges]]
        costs += [model.edge_cost, model.edge_cost[refund_edges] - model.edge_refund[refund_edges]]
        # Sink arcs from the last step.
        last = np.flatnonzero(k_of == self.n_steps - 1)
        tails.append(last + n)
        heads.append(np.full(len(last), self.sink))
        costs.append(np.zeros(len(last), np.int64))
        first += len(last)
        # Per open step a hub through which its impeded nodes pass in state 1, with at least
        # one unit forced through it: "some CAV impeded at k" as a network (a unit may leave
        # the hub by another impeded node than it came in by: a relaxation, branched on).
        self.step_impeded = {
            k: np.flatnonzero(model.impeded & (k_of == k)) for k in range(self.n_steps)
        }
        self.hub: dict[int, tuple[int, int, np.ndarray, np.ndarray, int]] = {}
        for j, k in enumerate(self.open_steps):
            nodes = self.step_impeded[k]
            hub_in, hub_out = 2 * n + 1 + 2 * j, 2 * n + 2 + 2 * j
            into = np.arange(first, first + len(nodes))
            out_of = into + len(nodes)
            middle = first + 2 * len(nodes)
            first = middle + 1
            tails += [nodes, np.full(len(nodes), hub_out), np.array([hub_in])]
            heads += [np.full(len(nodes), hub_in), nodes + n, np.array([hub_out])]
            costs += [model.node_cost[nodes], np.zeros(len(nodes), np.int64), np.zeros(1, np.int64)]
            self.hub[k] = (hub_in, hub_out, into, out_of, middle)
        self.n_arcs = first
        self.n_net_nodes = 2 * n + 1 + 2 * len(self.open_steps)
        self.tails = np.concatenate(tails).astype(np.int32)
        self.heads = np.concatenate(heads).astype(np.int32)
        self.costs = np.concatenate(costs).astype(np.int64)
        self.refundable_nodes = refundable
        self.refund_edges = refund_edges
        # Per open step: its impeded nodes, refundable nodes and refundable edges (by source).
        self.base_supply = np.zeros(self.n_net_nodes, np.int64)
        for row, col in model.problem.start_cells:
            node = model.node_at(0, (row, col))
            self.base_supply[node + n] += 1
        self.base_supply[self.sink] = -model.problem.n_cavs
        self.base_cap = np.ones(self.n_arcs, np.int64)
        for _, _, into, out_of, middle in self.hub.values():
            self.base_cap[into] = 0
            self.base_cap[out_of] = 0
            self.base_cap[middle] = 0
        self.base_cap[self.edge_arc] = model.upper[: model.n_edges]
        self.base_cap[self.edge_arc_refund[refund_edges]] = model.upper[refund_edges]
        # Blockers' fixed edges: out of the network, their unit moved into the supplies.
        self.constant = 0
        self.fixed_edges = np.flatnonzero(model.lower[: model.n_edges] > 0)
        for edge in self.fixed_edges.tolist():
            self.base_cap[self.edge_arc[edge]] = 0
            if self.edge_arc_refund[edge] >= 0:
                self.base_cap[self.edge_arc_refund[edge]] = 0
            self.base_supply[int(src[edge]) + n] -= 1
            self.base_supply[int(head[edge])] += 1
            self.constant += int(model.edge_cost[edge])  # blockers move at delta-fixed steps
        self.teleport = -1  # a hub node of the last flow entered and left unequally (or -1)
        from ortools.graph.python import min_cost_flow  # when first used (as solvers.py)

        self.solver = min_cost_flow.SimpleMinCostFlow()
        self.solver.add_arcs_with_capacity_and_unit_cost(
            self.tails, self.heads, self.base_cap, self.costs
        )
        self.all_arcs = np.arange(self.n_arcs, dtype=np.int32)
        self.all_nodes = np.arange(self.n_net_nodes, dtype=np.int32)

    def solve(self, branch: _Branch) -> tuple[int, np.ndarray, np.ndarray] | None:
        """Flow cost, node use and edge use of the branch's relaxation (None: infeasible)."""
        model, n = self.model, self.model.n_nodes
        self.teleport = -1
        cap = self.base_cap.copy()
        supply = self.base_supply.copy()
        constant = self.constant
        k_src = model.node_k[model.edge_src]
        hubs: list[int] = []
        # Default (delta fixed or open): refunded variants off; then per open step.
        cap[self.node_arc_refund[self.refundable_nodes]] = 0
        cap[self.edge_arc_refund[self.refund_edges]] = 0
        for k in self.open_steps:
            state = branch.states.get(k, OPEN)
            nodes = self.refundable_nodes[model.node_k[self.refundable_nodes] == k]
            edges = self.refund_edges[k_src[self.refund_edges] == k]
            if state != ZERO:  # regroup waived: the refunded node variant
                cap[self.node_arc[nodes]] = 0
                cap[self.node_arc_refund[nodes]] = 1
            if state != ONE:  # lateral moves free: the refunded edge variant
                base = self.base_cap[self.edge_arc[edges]]
                cap[self.edge_arc[edges]] = 0
                cap[self.edge_arc_refund[edges]] = base
            if state == ZERO:
                cap[self.node_arc[self.step_impeded[k]]] = 0
            elif state == ONE and not any(model.node_k[f] == k for f in branch.forced):
                hub_in, hub_out, into, out_of, middle = self.hub[k]
                nodes = self.step_impeded[k]
                cap[self.node_arc[nodes]] = 0
                cap[into] = 1
                cap[out_of] = 1
                cap[middle] = model.problem.n_cavs - 1
                supply[hub_in] -= 1
                supply[hub_out] += 1
                hubs.append(k)
        for node in branch.banned:
            cap[self.node_arc[node]] = 0
            k = int(model.node_k[node])
            if k in self.hub:
                position = int(np.searchsorted(self.step_impeded[k], node))
                cap[self.hub[k][2][position]] = 0
                cap[self.hub[k][3][position]] = 0
        for edge in branch.cut:
            cap[self.edge_arc[edge]] = 0
            if self.edge_arc_refund[edge] >= 0:
                cap[self.edge_arc_refund[edge]] = 0
        for node in branch.forced:  # impeded: one node arc, its cost fixed
            arc = self.node_arc[node]
            cap[arc] = 0
            supply[node] -= 1
            supply[node + n] += 1
            constant += int(self.costs[arc])
        solver = self.solver
        solver.set_arc_capacities(self.all_arcs, cap)
        solver.set_nodes_supplies(self.all_nodes, supply)
        if solver.solve() != solver.OPTIMAL:
            return None
        flows = solver.flows(self.all_arcs)
        node_use = np.zeros(n, np.int64)
        inner = self.node_arc >= 0
        node_use[inner] = flows[self.node_arc[inner]]
        has_refund = self.node_arc_refund >= 0
        node_use[has_refund] += flows[self.node_arc_refund[has_refund]]
        for node in branch.forced:
            node_use[node] = 1
        # Hub steps: a node's use is what came in by it; a unit that left by another node is
        # a teleport (returned so that the caller branches on it).
        teleport = -1
        for k in hubs:
            _, _, into, out_of, _ = self.hub[k]
            nodes = self.step_impeded[k]
            came, left = flows[into], flows[out_of]
            node_use[nodes] = came
            differs = np.flatnonzero(came != left)
            if len(differs) and teleport < 0:
                teleport = int(nodes[differs[0]])
        self.teleport = teleport
        edge_use = flows[self.edge_arc].copy()
        has = self.edge_arc_refund >= 0
        edge_use[has] += flows[self.edge_arc_refund[has]]
        edge_use[self.fixed_edges] = 1
        return int(solver.optimal_cost()) + constant, node_use, edge_use

    def true_cost(self, node_use: np.ndarray, edge_use: np.ndarray) -> int:
        """The model's objective of a flow, delta from the CAVs it keeps impeded."""
        model = self.model
        delta = self.actual_delta(node_use)
        cost = int(model.node_cost @ node_use + model.edge_cost @ edge_use)
        refund_node = (model.node_refund > 0) & (delta[model.node_k] == 1)
        cost -= int(model.node_refund[refund_node] @ node_use[refund_node])
        k_src = model.node_k[model.edge_src]
        refund_edge = (model.edge_refund > 0) & (delta[k_src] == 0)
        cost -= int(model.edge_refund[refund_edge] @ edge_use[refund_edge])
        return cost

    def actual_delta(self, node_use: np.ndarray) -> np.ndarray:
        delta = np.zeros(self.n_steps, np.int64)
        used = self.model.node_k[(node_use > 0) & self.model.impeded]
        delta[np.unique(used)] = 1
        return delta


def solve_network(
    model: FlowModel,
    time_limit_s: float,
    max_branches: int = 2000,
    hint: list[int] | None = None,
    max_work: int | None = None,
    plan_work: int | None = None,
) -> NetworkResult:
    """Best-bound branch and bound (see the module docstring) within ``max_branches`` flows,
    and within ``max_work`` if given: flows times the network's arcs (at least 2 flows).

    ``hint``: edge values of a plan (e.g. the shifted last one), a first upper bound if it is a
    plan of this model. Before branching, plans that keep nobody impeded from some open step on
    (and, before it, the cheapest) are tried as first upper bounds (one flow each).
    ``time_limit_s`` is a wall-clock safety net only; the flow count is what binds.
    ``plan_work``: a smaller work budget that ends the search once it has a plan (at least 2
    flows); without a plan it goes on within ``max_work``.
    """
    started = time.perf_counter()
    net = _Network(model)
    pairs = model.swap_pairs
    if max_work is not None:
        max_branches = min(max_branches, max(2, max_work // max(net.n_arcs, 1)))
    search = _Search(net, started, time_limit_s, max_branches)
    if plan_work is not None:
        search.plan_budget = max(2, plan_work // max(net.n_arcs, 1))
    if hint is not None:
        search.offer_hint(np.asarray(hint[: model.n_edges], np.int64))
    root = _Branch(0, 0, {})
    solved = search.solve(root)
    if solved is None:
        if search.out_of_budget:
            return NetworkResult("limit", branches=search.branches, message="limit")
        return NetworkResult("infeasible", branches=search.branches, message="no flow")
    queue: list[_Branch] = []
    counter = 0

    def expand(branch: _Branch, solved: tuple[int, np.ndarray, np.ndarray]) -> None:
        nonlocal counter
        bound, node_use, edge_use = solved
        if search.best_cost is not None and bound >= search.best_cost:
            return
        if net.teleport >= 0:  # not a plan: that node used, or not
            node = net.teleport
            children = [
                (branch.states, branch.forced | {node}, branch.banned, branch.cut),
                (branch.states, branch.forced, branch.banned | {node}, branch.cut),
            ]
        else:
            swap = next((p for p in pairs if edge_use[p[0]] and edge_use[p[1]]), None)
            cost = net.true_cost(node_use, edge_use)
            if swap is None:
                search.offer(cost, edge_use)
                if cost == bound:
                    return  # the relaxation's flow is a plan at the relaxation's cost
            children = _children(net, branch, node_use, edge_use, swap)
        for child in children:
            counter += 1
            heapq.heappush(queue, _Branch(bound, counter, *child))

    expand(root, solved)
    if queue and net.open_steps:
        search.dive_prefixes()
    while queue and not search.out_of_budget:
        branch = heapq.heappop(queue)
        if search.best_cost is not None and branch.bound >= search.best_cost:
            queue.clear()  # best bound first: nothing left can improve
            break
        solved = search.solve(branch)
        if solved is not None:
            expand(branch, solved)
    best = search.best_cost
    if best is None:
        if not queue:
            return NetworkResult("infeasible", branches=search.branches, message="no plan")
        lower = min(b.bound for b in queue)
        return NetworkResult("limit", bound=lower, branches=search.branches, message="limit")
    values = [int(v) for v in search.best_edges.tolist()]
    if not queue:
        return NetworkResult("optimal", values, best, best, search.branches, "proved")
    lower = min(min(b.bound for b in queue), best)
    return NetworkResult("feasible", values, best, lower, search.branches, "flow limit")


class _Search:
    """Flow budget and best plan of one search."""

    def __init__(self, net: _Network, started: float, time_limit_s: float, budget: int) -> None:
        self.net = net
        self.started = started
        self.time_limit_s = time_limit_s
        self.budget = budget
        self.plan_budget = budget  # flows after which a search with a plan stops
        self.branches = 0
        self.best_cost: int | None = None
        self.best_edges: np.ndarray | None = None
        self.trace: list[tuple[float, int]] = []  # (seconds, cost) of each better plan
        self.solved: dict[tuple, tuple] = {}

    @property
    def out_of_budget(self) -> bool:
        if self.branches >= self.budget or time.perf_counter() - self.started > self.time_limit_s:
            return True
        return self.best_cost is not None and self.branches >= self.plan_budget

    def solve(self, branch: _Branch) -> tuple[int, np.ndarray, np.ndarray] | None:
        """The branch's flow; a branch solved before (a dive's) is not solved again."""
        key = (tuple(sorted(branch.states.items())), branch.forced, branch.banned, branch.cut)
        if key in self.solved:
            solved, self.net.teleport = self.solved[key]
            return solved
        self.branches += 1
        solved = self.net.solve(branch)
        self.solved[key] = (solved, self.net.teleport)
        return solved

    def offer(self, cost: int, edge_use: np.ndarray) -> None:
        if self.best_cost is None or cost < self.best_cost:
            self.best_cost, self.best_edges = cost, edge_use
            self.trace.append((time.perf_counter() - self.started, cost))

    def offer_hint(self, edge_use: np.ndarray) -> None:
        """Take the hint's edges as a plan if they are one of this model (no flow solved)."""
        net, model = self.net, self.net.model
        if len(edge_use) != model.n_edges or edge_use.min(initial=0) < 0:
            return
        if (edge_use < model.lower[: model.n_edges]).any():
            return
        if (edge_use > model.upper[: model.n_edges]).any():
            return
        n = model.n_nodes
        inflow = np.bincount(model.edge_dst, weights=edge_use, minlength=n)
        outflow = np.bincount(model.edge_src, weights=edge_use, minlength=n)
        supply = np.zeros(n)
        for cell in model.problem.start_cells:
            supply[model.node_at(0, cell)] += 1
        last = model.node_k == net.n_steps - 1
        if (inflow > 1).any() or (inflow + supply != np.where(last, inflow, outflow)).any():
            return
        if any(edge_use[a] and edge_use[b] for a, b in model.swap_pairs):
            return
        self.offer(net.true_cost(inflow.astype(np.int64), edge_use), edge_use)

    def dive_prefixes(self) -> None:
        """Plans that keep CAVs impeded up to an open step at most and nobody from it on:
        the last impeded step tried from the front until a plan is no cheaper than the best."""
        worse = 0
        steps = self.net.open_steps
        for t in range(len(steps) + 1):
            if self.out_of_budget or worse >= 1:
                return
            states = {k: (ONE if j < t else ZERO) for j, k in enumerate(steps)}
            before = self.best_cost
            solved = self.solve(_Branch(0, 0, states))
            if solved is None or self.net.teleport >= 0:
                worse += t > 0
                continue
            _, node_use, edge_use = solved
            if any(edge_use[a] and edge_use[b] for a, b in self.net.model.swap_pairs):
                continue
            self.offer(self.net.true_cost(node_use, edge_use), edge_use)
            worse = 0 if self.best_cost != before else worse + 1


def _children(
    net: _Network,
    branch: _Branch,
    node_use: np.ndarray,
    edge_use: np.ndarray,
    swap: tuple[int, int] | None,
) -> list[tuple]:
    """The sub-branches that split ``branch`` where its flow is not a plan at its cost."""
    model = net.model
    states, forced, banned, cut = branch.states, branch.forced, branch.banned, branch.cut
    if swap is not None:
        a, b = swap
        return [(states, forced, banned, cut | {a}), (states, forced, banned, cut | {b})]
    delta = net.actual_delta(node_use)
    k_src = model.node_k[model.edge_src]
    gaps = {}
    for k in net.open_steps:
        if states.get(k, OPEN) != OPEN:
            continue
        # What step k's true cost exceeds its relaxed cost by: the lateral moves out of it if
        # a CAV is impeded there, else the regroup costs waived at it.
        if delta[k]:
            edges = (model.edge_refund > 0) & (k_src == k)
            gaps[k] = int(model.edge_refund[edges] @ edge_use[edges])
        else:
            nodes = (model.node_refund > 0) & (model.node_k == k)
            gaps[k] = int(model.node_refund[nodes] @ node_use[nodes])
    gaps = {k: gap for k, gap in gaps.items() if gap > 0}
    if gaps:
        k = min(gaps)  # the first (measured: fewer flows than the largest gap first)
        return [
            ({**states, k: ZERO}, forced, banned, cut),
            ({**states, k: ONE}, forced, banned, cut),
        ]
    # Every open step consistent and every hub without a teleport: cost == bound, so this
    # cannot happen (a planner turns the exception into an ERROR plan).
    raise AssertionError("network branch and bound: no branching step")
