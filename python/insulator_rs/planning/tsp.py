"""Exact travelling-salesman tours (closed, starting and ending at node 0).

Two exact solvers: Held-Karp dynamic programming (O(n^2 2^n), vectorised over
the last node; used up to :data:`HELD_KARP_MAX_NODES`), and OR-Tools CP-SAT
with an ``AddCircuit`` constraint, which must report OPTIMAL (a proof, not a
time-out) or the call fails. CP-SAT works on integer costs: costs are rounded
to :data:`CPSAT_RESOLUTION` s, so its tour is optimal for the rounded costs and
within n * resolution / 2 of the true optimum; the tour's cost is reported on
the original costs. Costs may be asymmetric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ortools.sat.python import cp_model

HELD_KARP_MAX_NODES = 13
CPSAT_RESOLUTION = 1e-4
CPSAT_TIME_LIMIT_S = 120.0


@dataclass(frozen=True)
class Tour:
    """A closed tour: ``order`` lists the nodes from 0 (the return to 0 is implied);
    ``cost`` is the sum of the edge costs including the return; ``method`` names the solver."""

    order: tuple[int, ...]
    cost: float
    method: str


def _check_costs(costs: np.ndarray) -> np.ndarray:
    c = np.asarray(costs, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] < 1:
        raise ValueError(f"costs: expected a square (n, n) matrix, got shape {c.shape}")
    off = c[~np.eye(len(c), dtype=bool)]
    if not np.all(np.isfinite(off)) or np.any(off < 0):
        raise ValueError("costs: off-diagonal entries must be finite and >= 0")
    return c


def tour_cost(costs: np.ndarray, order: tuple[int, ...] | list[int]) -> float:
    """Cost of the closed tour ``order`` (starting at node 0, returning to it)."""
    c = np.asarray(costs, dtype=np.float64)
    seq = list(order) + [order[0]]
    return float(sum(c[a, b] for a, b in zip(seq[:-1], seq[1:])))


def held_karp(costs: np.ndarray) -> Tour:
    """Exact optimal tour by Held-Karp dynamic programming (n <= HELD_KARP_MAX_NODES + 3)."""
    c = _check_costs(costs)
    n = len(c)
    if n > HELD_KARP_MAX_NODES + 3:
        raise ValueError(f"costs: Held-Karp is limited to {HELD_KARP_MAX_NODES + 3} nodes, got {n}")
    if n <= 2:
        order = tuple(range(n))
        return Tour(order, tour_cost(c, order), "held-karp")
    k = n - 1  # nodes 1..n-1 are bit 0..k-1
    size = 1 << k
    dp = np.full((size, k), np.inf)
    parent = np.full((size, k), -1, dtype=np.int64)
    for j in range(k):
        dp[1 << j, j] = c[0, j + 1]
    sub = c[1:, 1:]
    bits = np.arange(k)
    for mask in range(1, size):
        members = bits[(mask >> bits) & 1 == 1]
        if len(members) < 2:
            continue
        for j in members:
            prev = mask ^ (1 << j)
            cand = dp[prev, members] + sub[members, j]
            cand[members == j] = np.inf
            best = int(np.argmin(cand))
            dp[mask, j] = cand[best]
            parent[mask, j] = members[best]
    full = size - 1
    totals = dp[full] + c[1:, 0]
    last = int(np.argmin(totals))
    order_rev = []
    mask, j = full, last
    while j >= 0:
        order_rev.append(j + 1)
        pj = int(parent[mask, j])
        mask ^= 1 << j
        j = pj
    order = (0, *reversed(order_rev))
    return Tour(order, tour_cost(c, order), "held-karp")


def cpsat_tour(costs: np.ndarray, *, time_limit_s: float = CPSAT_TIME_LIMIT_S,
               workers: int = 2) -> Tour:
    """Exact optimal tour by CP-SAT with a circuit constraint; raises RuntimeError unless the
    solver proves optimality within ``time_limit_s``."""
    c = _check_costs(costs)
    n = len(c)
    if n <= 2:
        order = tuple(range(n))
        return Tour(order, tour_cost(c, order), "cp-sat")
    model = cp_model.CpModel()
    arcs = []
    lits = {}
    for i in range(n):
        for j in range(n):
            if i != j:
                lit = model.new_bool_var(f"x{i}_{j}")
                lits[i, j] = lit
                arcs.append((i, j, lit))
    model.add_circuit(arcs)
    model.minimize(sum(int(round(c[i, j] / CPSAT_RESOLUTION)) * lit for (i, j), lit in lits.items()))
    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = time_limit_s
    solver.parameters.num_workers = workers
    status = solver.solve(model)
    if status != cp_model.OPTIMAL:
        raise RuntimeError(f"CP-SAT did not prove optimality (status {solver.status_name(status)}) "
                           f"for {n} nodes within {time_limit_s} s")
    succ = {i: j for (i, j), lit in lits.items() if solver.value(lit)}
    seq = [0]
    while len(seq) < n:
        seq.append(succ[seq[-1]])
    return Tour(tuple(seq), tour_cost(c, seq), "cp-sat")


def solve_tour(costs: np.ndarray) -> Tour:
    """The exact optimal closed tour from node 0: Held-Karp when it fits, else CP-SAT."""
    c = _check_costs(costs)
    return held_karp(c) if len(c) <= HELD_KARP_MAX_NODES else cpsat_tour(c)
