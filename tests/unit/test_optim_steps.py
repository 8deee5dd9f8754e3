"""Step-by-step tests of H-GWO, GWO, PSO and DE against the paper's formulas, re-derived by hand.

Each test copies the optimiser's random generator just before an ``ask()`` (``replay``), draws
the same random numbers from the copy in the order the optimiser consumes them, and recomputes
the expected batch with plain NumPy/Python from the published formulas (the paper's Section 3,
read as in ``docs/benchmarks.md``, "Choices where the paper is ambiguous"). Nothing expected
here comes from calling the code under test: the only thing shared with it is the order of the
random draws, which each ``*_by_hand`` helper states.

Costs are handed to ``tell()`` directly, so selection rules (greedy ``<=``, pbest ``<``,
unconditional GWO replacement, ties) are checked on crafted costs. Scenario guards (``assert
... > 0`` on counters) make sure the seed really exercises the branch a test is about (an
out-of-box component, a forced crossover index that matters, an active velocity clamp), so a
test cannot pass only because its branch never ran.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np
import pytest

from hhra_phys.optim import DE, GWO, HGWO, PSO, Optimiser
from hhra_phys.optim.gwo import gwo_a

LO = np.array([-1.0, 2.0, -3.0])
HI = np.array([1.0, 5.0, 2.0])
BOUNDS = np.column_stack([LO, HI])
# optimum inside the box, away from its centre and from the origin; the box excludes the
# origin in dimension 1, so H-GWO's lam*X_alpha mutants fall outside there and get re-drawn
CENTRE = np.array([0.3, 4.0, -2.5])
N = 5


def sphere(x: np.ndarray) -> np.ndarray:
    """Shifted sphere, one cost per row."""
    return np.sum((np.atleast_2d(x) - CENTRE) ** 2, axis=1)


def replay(opt: Optimiser) -> np.random.Generator:
    """A copy of ``opt``'s generator: it yields exactly the draws of the next ``ask()``."""
    return copy.deepcopy(opt.rng)


# -- the paper's steps, written independently of hhra_phys.optim ------------------------------


def tent_by_hand(g: np.random.Generator, n: int, d: int) -> np.ndarray:
    """Tent map (eq. 24), one sequence per dimension. Draws: ``phi`` (d), start (d)."""
    phi = g.uniform(1e-3, 1.0 - 1e-3, d)
    x = list(g.random(d))
    rows = []
    for _ in range(n):
        x = [xj / pj if xj < pj else (1.0 - xj) / (1.0 - pj) for xj, pj in zip(x, phi, strict=True)]
        # a degenerate iterate would make the optimiser draw a replacement: not replayed here
        assert all(1e-12 < xj < 1.0 - 1e-12 for xj in x), "seed hits a degenerate iterate"
        rows.append(x)
    return np.array(rows)


def best_distinct_by_hand(points: np.ndarray, costs: np.ndarray, k: int) -> list[int]:
    """Indices of the ``k`` best rows, skipping a row equal to one already kept."""
    kept: list[int] = []
    for i in sorted(range(len(costs)), key=lambda i: costs[i]):  # sorted() is stable
        if not any(np.array_equal(points[i], points[j]) for j in kept):
            kept.append(i)
        if len(kept) == k:
            break
    return kept


def leaders_by_hand(points: np.ndarray, costs: np.ndarray) -> np.ndarray:
    """Alpha, beta, delta: the three best distinct points among all evaluated so far."""
    return points[best_distinct_by_hand(points, costs, 3)]


def gwo_move_by_hand(
    g: np.random.Generator, wolves: np.ndarray, leaders: np.ndarray, a: float
) -> np.ndarray:
    """Eqs. 16-19. Draws: ``r1`` then ``r2``, each (leader, wolf, component)."""
    n, d = wolves.shape
    r = g.random((2, 3, n, d))
    x_sum = np.zeros((n, d))
    for k in range(3):  # k = 0, 1, 2: alpha, beta, delta
        big_a = 2.0 * a * r[0, k] - a
        big_c = 2.0 * r[1, k]
        dist = np.abs(big_c * leaders[k] - wolves)
        x_sum += leaders[k] - big_a * dist  # X1, X2, X3
    return x_sum / 3.0


def picks_by_hand(
    g: np.random.Generator, n: int, k: int, exclude: Sequence[Sequence[int]]
) -> list[list[int]]:
    """``k`` distinct indices per row, none in ``exclude[i]``. Draws: one key per (row, index);
    a row picks its allowed indices with the smallest keys (uniform without replacement)."""
    keys = g.random((n, n))
    return [
        sorted((c for c in range(n) if c not in exclude[i]), key=lambda c: keys[i, c])[:k]
        for i in range(n)
    ]


def crossover_by_hand(
    g: np.random.Generator, mutant: np.ndarray, target: np.ndarray, cr: float | None
) -> tuple[np.ndarray, int]:
    """Eq. 21. Draws per row: d uniforms, then ``Cr``'s uniform, then ``R``'s uniform.

    Returns the trial and how many components came from the mutant *only* because of the
    forced index (the scenario guard for ``j == R``).
    """
    n, d = target.shape
    u = g.random((n, d + 2))
    out = target.copy()
    forced_only = 0
    for i in range(n):
        rate = 0.5 * (1.0 + u[i, d]) if cr is None else cr
        big_r = int(np.floor(u[i, d + 1] * d))  # uniform over the d dimensions
        assert 0 <= big_r < d
        for j in range(d):
            if u[i, j] <= rate or j == big_r:
                out[i, j] = mutant[i, j]
                forced_only += int(u[i, j] > rate and mutant[i, j] != target[i, j])
    return out, forced_only


def redraw_by_hand(g: np.random.Generator, x: np.ndarray) -> tuple[np.ndarray, int]:
    """Eq. 22: out-of-box components re-drawn uniformly inside, in row-major order."""
    out = x.copy()
    outside = [
        (i, j)
        for i in range(x.shape[0])
        for j in range(x.shape[1])
        if not LO[j] <= x[i, j] <= HI[j]
    ]
    if outside:
        for (i, j), u in zip(outside, g.random(len(outside)), strict=True):
            out[i, j] = LO[j] + u * (HI[j] - LO[j])
    return out, len(outside)


def clip_by_hand(x: np.ndarray) -> tuple[np.ndarray, int]:
    """Nearest limit for out-of-box components; also how many there were."""
    outside = int(np.sum((x < LO) | (x > HI)))
    return np.minimum(np.maximum(x, LO), HI), outside


def schedule_a(t: int, max_iter: int) -> float:
    """``a = 2 - 2t/MaxIter`` for the move made after ``t`` iterations."""
    return 2.0 - 2.0 * t / max_iter


# -- H-GWO --------------------------------------------------------------------------------------


def test_hgwo_initialisation_tent_map_opposition_best_n() -> None:
    x0 = np.array([[0.9, 2.1, 1.5]])  # a poor warm start whose opposite is good
    opt = HGWO(BOUNDS, N, max_iter=4, seed=0, x0=x0)
    g = replay(opt)
    batch = opt.ask()

    p = LO + tent_by_hand(g, N, 3) * (HI - LO)
    p[0] = x0[0]  # x0 replaces the first tent point before the opposites are formed
    op = np.array([[LO[j] + HI[j] - p[i, j] for j in range(3)] for i in range(N)])
    np.testing.assert_allclose(batch, np.vstack([p, op]), rtol=0, atol=1e-12)

    costs = sphere(batch)
    opt.tell(costs)
    keep = best_distinct_by_hand(batch, costs, N)
    # the seed makes both P and OP contribute, drops x0 and keeps its opposite
    assert any(k < N for k in keep) and 0 not in keep and N in keep
    np.testing.assert_array_equal(opt.population, batch[keep])
    np.testing.assert_array_equal(opt.costs, costs[keep])
    np.testing.assert_array_equal(opt.leaders, leaders_by_hand(batch, costs))
    assert opt.nfev == 2 * N


def test_hgwo_initialisation_removes_duplicates() -> None:
    # two identical warm starts at the optimum: their tent rows and their opposites are equal
    x0 = np.array([CENTRE, CENTRE])
    opt = HGWO(BOUNDS, N, max_iter=4, seed=4, x0=x0)
    batch = opt.ask()
    costs = sphere(batch)
    opt.tell(costs)
    keep = best_distinct_by_hand(batch, costs, N)
    assert 1 not in keep and N + 1 not in keep  # the duplicates ranked in the best n were dropped
    np.testing.assert_array_equal(opt.population, batch[keep])
    assert len({tuple(row) for row in opt.population}) == N
    np.testing.assert_array_equal(opt.leaders[0], CENTRE)


def test_gwo_a_schedule() -> None:
    for t, horizon in [(0, 10), (1, 10), (5, 10), (9, 10), (10, 10), (3, 7)]:
        assert gwo_a(t, horizon) == pytest.approx(2.0 - 2.0 * t / horizon)


def hgwo_expected_batch(
    opt: HGWO, g: np.random.Generator, seen_x: np.ndarray, seen_f: np.ndarray
) -> tuple[np.ndarray, dict[str, int]]:
    """Steps 6-8 of one H-GWO iteration from the pack and every point evaluated so far."""
    x, f = opt.population, opt.costs
    n = x.shape[0]
    leaders = leaders_by_hand(seen_x, seen_f)
    a = schedule_a(opt.nit, opt.max_iter)
    moved, n_clip = clip_by_hand(gwo_move_by_hand(g, x, leaders, a))
    alpha = int(np.argmin(f))  # alpha's index in the current pack
    picks = picks_by_hand(g, n, 2, [[alpha]] * n)  # r1 != r2, both != alpha
    mutant = np.array([opt.lam * leaders[0] + opt.F * (x[r1] - x[r2]) for r1, r2 in picks])
    cross, forced = crossover_by_hand(g, mutant, moved, opt.Cr)
    trial, n_redraw = redraw_by_hand(g, cross)
    expected = np.vstack([moved, trial]) if opt.target_vector == "moved" else trial
    return expected, {"clip": n_clip, "forced": forced, "redraw": n_redraw}


@pytest.mark.parametrize("target_vector", ["moved", "previous"])
def test_hgwo_iterations_follow_the_paper(target_vector: str) -> None:
    opt = HGWO(BOUNDS, N, max_iter=4, seed=11, target_vector=target_vector, F=0.7, lam=0.25)
    batch = opt.ask()
    costs = sphere(batch)
    opt.tell(costs)
    seen_x, seen_f = batch, costs
    guards = {"clip": 0, "forced": 0, "redraw": 0}
    while not opt.done:
        g = replay(opt)
        expected, used = hgwo_expected_batch(opt, g, seen_x, seen_f)
        for key in guards:
            guards[key] += used[key]
        before_x, before_f = opt.population.copy(), opt.costs.copy()
        batch = opt.ask()
        np.testing.assert_allclose(batch, expected, rtol=0, atol=1e-12)
        costs = sphere(batch)
        opt.tell(costs)
        # greedy one-to-one selection (eq. 23): the trial wins ties
        if target_vector == "moved":
            tgt, tgt_f, tri, tri_f = batch[:N], costs[:N], batch[N:], costs[N:]
        else:
            tgt, tgt_f, tri, tri_f = before_x, before_f, batch, costs
        for i in range(N):
            want = tri[i] if tri_f[i] <= tgt_f[i] else tgt[i]
            np.testing.assert_array_equal(opt.population[i], want)
        seen_x, seen_f = np.vstack([seen_x, batch]), np.concatenate([seen_f, costs])
        np.testing.assert_array_equal(opt.leaders, leaders_by_hand(seen_x, seen_f))
    assert opt.nit == 4
    # the seed exercised every branch the replay claims to check
    assert guards["forced"] > 0 and guards["redraw"] > 0 and guards["clip"] > 0, guards


def test_hgwo_alpha_excluded_from_difference_vectors() -> None:
    # with lam = 1, F = 1 and Cr = 1 the trial is alpha + X_r1 - X_r2 (nothing re-drawn in a
    # huge box); pack members at distinct powers of two make (r1, r2) readable from the trial
    big = [(-1e3, 1e3)]
    opt = HGWO(big, 6, max_iter=50, seed=5, lam=1.0, F=1.0, Cr=1.0)
    opt.ask()
    opt.tell(np.arange(12.0))
    for _ in range(40):
        opt.population = np.array([[1.0], [2.0], [4.0], [8.0], [16.0], [32.0]])
        opt.costs = np.array([3.0, 1.0, 2.0, 4.0, 5.0, 6.0])  # alpha is member 1 (value 2)
        opt.leaders = np.array([[2.0], [4.0], [1.0]])
        opt.leader_costs = np.array([1.0, 2.0, 3.0])
        trial = opt.ask()[6:, 0]
        opt.tell(np.full(12, 100.0))
        for v in trial - 2.0:  # X_r1 - X_r2 with members 2**k
            pairs = [(i, j) for i in range(6) for j in range(6) if 2.0**i - 2.0**j == v]
            assert len(pairs) == 1, v
            i, j = pairs[0]
            assert i != j and 1 not in (i, j)


def test_hgwo_forced_crossover_index_with_cr_zero() -> None:
    # Cr = 0: only the forced component j = R comes from the mutant, R uniform over dimensions
    opt = HGWO(BOUNDS, N, max_iter=30, seed=2, Cr=0.0)
    opt.tell(sphere(opt.ask()))
    seen = set()
    while not opt.done:
        g = replay(opt)
        n, d = N, 3
        g.random((2, 3, n, d))  # GWO move
        g.random((n, n))  # r1, r2 picks
        u = g.random((n, d + 2))
        forced = np.floor(u[:, d + 1] * d).astype(int)
        batch = opt.ask()
        moved, trial = batch[:N], batch[N:]
        for i in range(N):
            differs = np.flatnonzero(trial[i] != moved[i])
            assert differs.tolist() == [forced[i]]
        seen.update(forced.tolist())
        opt.tell(sphere(batch))
    assert seen == {0, 1, 2}


def test_hgwo_greedy_selection_on_crafted_costs() -> None:
    opt = HGWO(BOUNDS, N, max_iter=4, seed=8)
    first = opt.ask()
    f0 = sphere(first)
    opt.tell(f0)
    batch = opt.ask()
    moved_f = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    trial_f = np.array([0.5, 2.0, 4.0, 4.0, 9.0])  # wins, tie, loses, tie, loses
    opt.tell(np.concatenate([moved_f, trial_f]))
    take_trial = np.array([True, True, False, True, False])
    want = np.where(take_trial[:, None], batch[N:], batch[:N])
    np.testing.assert_array_equal(opt.population, want)
    np.testing.assert_array_equal(opt.costs, [0.5, 2.0, 3.0, 4.0, 5.0])
    # on a tie the losing moved wolf is discarded, so the leaders come from the previous
    # leaders and the new pack (not from every point evaluated)
    old = leaders_by_hand(first, f0)
    old_f = np.sort(f0)[:3]
    pool_x, pool_f = np.vstack([old, want]), np.concatenate([old_f, opt.costs])
    np.testing.assert_array_equal(opt.leaders, leaders_by_hand(pool_x, pool_f))


# -- GWO ----------------------------------------------------------------------------------------


def test_gwo_initialisation_and_moves() -> None:
    x0 = np.array([0.0, 3.0, 0.0])
    opt = GWO(BOUNDS, N, max_iter=5, seed=21, x0=x0)
    g = replay(opt)
    batch = opt.ask()
    want = LO + g.random((N, 3)) * (HI - LO)
    want[0] = x0
    np.testing.assert_allclose(batch, want, rtol=0, atol=1e-12)
    costs = sphere(batch)
    opt.tell(costs)
    seen_x, seen_f = batch, costs
    clipped = 0
    while not opt.done:
        g = replay(opt)
        leaders = leaders_by_hand(seen_x, seen_f)
        a = schedule_a(opt.nit, opt.max_iter)
        want, n_out = clip_by_hand(gwo_move_by_hand(g, opt.population, leaders, a))
        clipped += n_out
        batch = opt.ask()
        np.testing.assert_allclose(batch, want, rtol=0, atol=1e-12)
        costs = sphere(batch)
        opt.tell(costs)
        seen_x, seen_f = np.vstack([seen_x, batch]), np.concatenate([seen_f, costs])
        np.testing.assert_array_equal(opt.leaders, leaders_by_hand(seen_x, seen_f))
    assert clipped > 0


def test_gwo_replaces_pack_but_keeps_leaders() -> None:
    opt = GWO(BOUNDS, N, max_iter=3, seed=22)
    first = opt.ask()
    opt.tell(np.arange(1.0, N + 1.0))
    batch = opt.ask()
    worse = np.full(N, 50.0)  # every moved wolf is worse: GWO has no greedy selection
    opt.tell(worse)
    np.testing.assert_array_equal(opt.population, batch)
    np.testing.assert_array_equal(opt.costs, worse)
    np.testing.assert_array_equal(opt.leaders, first[:3])  # costs 1, 2, 3 in that order


# -- PSO ----------------------------------------------------------------------------------------


def test_pso_velocity_inertia_clamp_and_pbest() -> None:
    vmax = np.array([0.3, 0.5, 0.4])
    opt = PSO(BOUNDS, N, max_iter=5, seed=5, w_start=0.9, w_end=0.3, c1=1.5, c2=2.5, vmax=vmax)
    g = replay(opt)
    x = opt.ask()
    np.testing.assert_allclose(x, LO + g.random((N, 3)) * (HI - LO), rtol=0, atol=1e-12)
    f = sphere(x)
    opt.tell(f)
    v = np.zeros((N, 3))
    pbest, pbest_f = x.copy(), f.copy()
    gbest = x[int(np.argmin(f))]
    n_clamp = n_clip = 0
    for t in range(5):
        g = replay(opt)
        w = 0.9 + (0.3 - 0.9) * t / (5 - 1)  # linear from w_start (move 1) to w_end (move 5)
        r = g.random((2, N, 3))
        v = w * v + 1.5 * r[0] * (pbest - x) + 2.5 * r[1] * (gbest - x)
        n_clamp += int(np.sum(np.abs(v) > vmax))
        v = np.minimum(np.maximum(v, -vmax), vmax)
        x, out = clip_by_hand(x + v)
        n_clip += out
        batch = opt.ask()
        np.testing.assert_allclose(batch, x, rtol=0, atol=1e-12)
        f = sphere(batch)
        opt.tell(f)
        for i in range(N):
            if f[i] < pbest_f[i]:
                pbest[i], pbest_f[i] = batch[i], f[i]
            if f[i] < sphere(gbest)[0]:
                gbest = batch[i]
        np.testing.assert_array_equal(opt.pbest, pbest)
        np.testing.assert_array_equal(opt.x_best, gbest)
    assert n_clamp > 0 and n_clip > 0, (n_clamp, n_clip)


def test_pso_constant_inertia_and_pbest_ties() -> None:
    opt = PSO(BOUNDS, N, max_iter=3, seed=32, w=0.5, c1=0.0, c2=0.0, vmax=10.0)
    first = opt.ask()
    opt.tell(np.arange(1.0, N + 1.0))
    opt.velocity = np.full((N, 3), 0.01)  # with c1 = c2 = 0 only inertia moves a particle
    batch = opt.ask()
    np.testing.assert_allclose(batch, np.clip(first + 0.5 * 0.01, LO, HI), rtol=0, atol=1e-12)
    # equal cost keeps the old personal best, lower replaces it, higher keeps it
    opt.tell(np.array([1.0, 1.5, 3.0, 9.0, 5.0]))
    want = first.copy()
    want[1] = batch[1]
    np.testing.assert_array_equal(opt.pbest, want)


# -- DE -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("cr", [None, 0.3])
def test_de_generations_follow_rand_1_bin(cr: float | None) -> None:
    opt = DE(BOUNDS, N, max_iter=5, seed=41, F=0.8, Cr=cr)
    g = replay(opt)
    x = opt.ask()
    np.testing.assert_allclose(x, LO + g.random((N, 3)) * (HI - LO), rtol=0, atol=1e-12)
    f = sphere(x)
    opt.tell(f)
    n_redraw = forced = 0
    while not opt.done:
        g = replay(opt)
        pop = opt.population
        picks = picks_by_hand(g, N, 3, [[i] for i in range(N)])  # r1, r2, r3 all != i
        mutant = np.array([pop[a] + 0.8 * (pop[b] - pop[c]) for a, b, c in picks])
        cross, k = crossover_by_hand(g, mutant, pop, cr)
        forced += k
        trial, k = redraw_by_hand(g, cross)
        n_redraw += k
        batch = opt.ask()
        np.testing.assert_allclose(batch, trial, rtol=0, atol=1e-12)
        f_trial = sphere(batch)
        prev, prev_f = pop.copy(), opt.costs.copy()
        opt.tell(f_trial)
        for i in range(N):
            want = batch[i] if f_trial[i] <= prev_f[i] else prev[i]
            np.testing.assert_array_equal(opt.population[i], want)
    assert n_redraw > 0 and forced > 0, (n_redraw, forced)


def test_de_greedy_selection_ties_go_to_the_trial() -> None:
    opt = DE(BOUNDS, N, max_iter=3, seed=42)
    first = opt.ask()
    opt.tell(np.arange(1.0, N + 1.0))
    trial = opt.ask()
    opt.tell(np.array([0.5, 2.0, 4.0, 4.0, 9.0]))  # wins, tie, loses, tie, loses
    want = np.where(np.array([True, True, False, True, False])[:, None], trial, first)
    np.testing.assert_array_equal(opt.population, want)
