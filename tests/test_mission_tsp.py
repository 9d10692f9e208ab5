"""Exact TSP tours against brute force (N <= 9) and against each other."""

import itertools

import numpy as np
import pytest

from insulator_rs.planning.tsp import cpsat_tour, held_karp, solve_tour, tour_cost


def brute_force(costs):
    """Reference: every permutation of nodes 1..n-1 (itertools), exact."""
    n = len(costs)
    best = np.inf
    for perm in itertools.permutations(range(1, n)):
        best = min(best, tour_cost(costs, (0, *perm)))
    return best


def random_costs(n, seed, symmetric=True):
    rng = np.random.default_rng(seed)
    if symmetric:
        p = rng.uniform(0, 50, size=(n, 3))
        return np.linalg.norm(p[:, None] - p[None], axis=-1)
    c = rng.uniform(1, 30, size=(n, n))
    np.fill_diagonal(c, 0)
    return c


@pytest.mark.parametrize("n", range(2, 10))
@pytest.mark.parametrize("symmetric", [True, False])
def test_exact_solvers_match_brute_force(n, symmetric):
    """Reference: brute force over all (n-1)! tours; tolerance 1e-9 for Held-Karp (same float
    costs) and n * 1e-4 / 2 s for CP-SAT (its costs are rounded to 1e-4)."""
    c = random_costs(n, seed=n + 100 * symmetric, symmetric=symmetric)
    ref = brute_force(c)
    hk = held_karp(c)
    assert hk.cost == pytest.approx(ref, abs=1e-9)
    assert sorted(hk.order) == list(range(n)) and hk.order[0] == 0
    cp = cpsat_tour(c)
    assert abs(cp.cost - ref) <= n * 1e-4 / 2 + 1e-9
    assert sorted(cp.order) == list(range(n)) and cp.order[0] == 0


@pytest.mark.parametrize("n", [11, 13])
def test_held_karp_and_cpsat_agree_beyond_brute_force(n):
    c = random_costs(n, seed=n)
    assert abs(held_karp(c).cost - cpsat_tour(c).cost) <= n * 1e-4


def test_solve_tour_handles_25_nodes_with_proof():
    c = random_costs(25, seed=5)
    t = solve_tour(c)
    assert t.method == "cp-sat" and len(t.order) == 25
    assert t.cost == pytest.approx(tour_cost(c, t.order))


@pytest.mark.parametrize("bad, match", [
    (np.zeros((2, 3)), "square"),
    (np.array([[0, -1.0], [1.0, 0]]), ">= 0"),
    (np.array([[0, np.inf], [1.0, 0]]), "finite"),
])
def test_bad_costs(bad, match):
    with pytest.raises(ValueError, match=match):
        solve_tour(bad)
