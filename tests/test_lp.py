"""The dense interior-point LP solver (``grasp_jax._lp``) against SciPy's HiGHS."""

from __future__ import annotations

import functools

import _jit
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

from grasp_jax.lp import LP, Status, optimal_value, solve, warm_point

#: The warm-start and best-effort checks compare two programs bit for bit (``_jit.FUSION_EMITTERS``).
jit = functools.partial(_jit.jit, options=_jit.FUSION_EMITTERS)
ROWS, COLS = 5, 12  # one shape for every batch below: one compilation per transformation
BATCH = 40


def _feasible(rng, rows=ROWS, cols=COLS):
    """A random standard-form LP with a strictly feasible primal and dual (finite optimum)."""
    A = rng.normal(size=(rows, cols))
    x0 = rng.uniform(0.1, 2.0, size=cols)
    y0 = rng.normal(size=rows)
    s0 = rng.uniform(0.1, 2.0, size=cols)
    return A, A @ x0, A.T @ y0 + s0


def _infeasible(rng, rows=ROWS, cols=COLS):
    """A random LP with ``A x = b, x >= 0`` infeasible, by a planted Farkas vector ``y0``."""
    A = rng.normal(size=(rows, cols))
    y0 = rng.normal(size=rows)
    g = A.T @ y0
    # Make A^T y0 <= -slack column by column.
    A -= np.outer(y0, np.maximum(g, 0.0) + rng.uniform(0.05, 1.0, size=cols)) / (y0 @ y0)
    b = rng.normal(size=rows)
    b += (rng.uniform(0.2, 1.0) - b @ y0) * y0 / (y0 @ y0)  # b . y0 > 0
    c = rng.normal(size=cols)
    return A, b, c


def _rank_deficient(rng, kind: str):
    """A ``ROWS x COLS`` LP whose last row is a combination ``w`` of the others.

    ``"feasible"``: b consistent, strictly feasible primal and dual. ``"infeasible"``: an
    infeasible ``(ROWS - 1)``-row LP with its consistent combination appended (the planted Farkas
    vector, padded with 0, still certifies it). ``"inconsistent"``: b violates the row dependency,
    so every certificate is ``t (-w, 1)``, in the null space of ``A^T`` (``A^T y = 0, b.y > 0``).
    """
    if kind == "infeasible":
        A, b, c = _infeasible(rng, rows=ROWS - 1)
    else:
        A, b, c = _feasible(rng, rows=ROWS - 1)
    w = rng.normal(size=ROWS - 1)
    A = np.vstack([A, w @ A])
    b = np.append(b, w @ b)
    if kind == "inconsistent":
        b[-1] += rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0)
    return A, b, c


def _highs(A, b, c):
    return linprog(c, A_eq=A, b_eq=b, bounds=(0, None), method="highs")


_solve_batch = jit(jax.vmap(lambda A, b, c: solve(LP(A, b, c))[0]))


def _solve(problems):
    A, b, c = (jnp.asarray(np.stack(x)) for x in zip(*problems))
    sol = _solve_batch(A, b, c)
    return jax.tree_util.tree_map(np.asarray, sol)


@pytest.fixture(scope="module")
def problems():
    rng = np.random.default_rng(0)
    feasible = [_feasible(rng) for _ in range(BATCH)]
    infeasible = [_infeasible(rng) for _ in range(BATCH)]
    return feasible, infeasible


def test_status_enum():
    assert [int(s) for s in Status] == [0, 1, 2, 3, 4]
    assert Status.OPTIMAL.message.startswith("optimal")
    assert "infeasible" in Status.INFEASIBLE.message
    assert "not converged" in Status.NOT_CONVERGED.message
    assert "best iterate" in Status.APPROXIMATE.message
    assert "dual bound" in Status.BOUNDED.message


def test_feasible_matches_highs(problems):
    feasible, _ = problems
    sol = _solve(feasible)
    assert sol.status.dtype == np.int8
    assert np.all(sol.status == Status.OPTIMAL)
    for k, (A, b, c) in enumerate(feasible):
        ref = _highs(A, b, c)
        assert ref.status == 0
        assert sol.value[k] == pytest.approx(ref.fun, rel=1e-8, abs=1e-9)
        x = sol.x[k]
        assert np.all(x >= -1e-9)
        np.testing.assert_allclose(A @ x, b, atol=1e-8 * (1 + np.abs(b).max()))
        assert c @ x == pytest.approx(sol.value[k], rel=1e-12, abs=1e-12)
        # Dual feasibility and strong duality of the returned y.
        y = sol.y[k]
        assert np.all(c - A.T @ y >= -1e-8 * (1 + np.abs(c).max()))
        assert b @ y == pytest.approx(ref.fun, rel=1e-8, abs=1e-9)
        assert 0 < sol.iterations[k] <= 30
        assert sol.residual[k] <= 1e-9


_warm_batch = jit(jax.vmap(lambda A, b, c, x, y, s, w: solve(LP(A, b, c), warm=((x, y, s),), weight=w)[0]))


@pytest.mark.parametrize("step", [1e-4, 1e-2])
def test_warm_start_from_a_nearby_problem(problems, step):
    """Warm-started from a nearby problem's solution (Skajaa, Andersen and Ye's point), an LP
    reaches HiGHS's optimum in fewer iterations; weight 0 is the standard start itself; an
    infeasible problem is still certified from a warm start."""
    feasible, infeasible = problems
    rng = np.random.default_rng(3)
    near = [(A + step * rng.normal(size=A.shape), b, c) for A, b, c in feasible]
    first = _solve(feasible)
    A, b, c = (jnp.asarray(np.stack(x)) for x in zip(*near))
    point = jax.vmap(lambda A, b, c, x, y: warm_point(LP(A, b, c), first._replace(x=x, y=y)))(
        *(jnp.asarray(np.stack(x)) for x in zip(*feasible)), first.x, first.y)
    cold = _solve(near)
    # (every weight a weak-typed float64 array like 0.999's: one program)
    same = jax.tree_util.tree_map(np.asarray, _warm_batch(A, b, c, *point, jnp.full(BATCH, 0.0)))
    np.testing.assert_array_equal(same.x, cold.x)
    warm = jax.tree_util.tree_map(np.asarray, _warm_batch(A, b, c, *point, jnp.full(BATCH, 0.999)))
    assert np.all(warm.status == Status.OPTIMAL)
    for k, (Ak, bk, ck) in enumerate(near):
        assert warm.value[k] == pytest.approx(_highs(Ak, bk, ck).fun, rel=1e-7, abs=1e-8)  # stopped at 1e-9 gap
    assert np.mean(warm.iterations) < 0.75 * np.mean(cold.iterations)
    # from an unrelated problem's solution: still every verdict right
    Ai, bi, ci = (jnp.asarray(np.stack(x)) for x in zip(*infeasible))
    other = _warm_batch(Ai, bi, ci, *point, jnp.full(BATCH, 0.99))
    assert np.all(np.asarray(other.status) == Status.INFEASIBLE)


def test_infeasible_farkas_certificate(problems):
    _, infeasible = problems
    sol = _solve(infeasible)
    for k, (A, b, c) in enumerate(infeasible):
        assert _highs(A, b, c).status == 2
        assert sol.status[k] == Status.INFEASIBLE, k
        y = sol.y[k]
        assert b @ y == pytest.approx(1.0, rel=1e-10)
        aty = A.T @ y
        assert aty.max() <= 1e-6 * max(1.0, np.abs(aty).max()), aty.max()
        assert sol.value[k] == 0.0
        assert np.all(sol.x[k] == 0.0)


def test_mixed_batch_and_rank_deficient():
    """Feasible, infeasible and rank-deficient problems in one vmapped batch, interleaved."""
    rng = np.random.default_rng(1)
    kinds = ["feasible", "infeasible", "rankdef", "rankdef_infeasible"] * (BATCH // 4)
    makers = {
        "feasible": lambda: _feasible(rng),
        "infeasible": lambda: _infeasible(rng),
        "rankdef": lambda: _rank_deficient(rng, "feasible"),
        "rankdef_infeasible": lambda: _rank_deficient(rng, "infeasible"),
    }
    problems = [makers[kind]() for kind in kinds]
    sol = _solve(problems)
    for k, ((A, b, c), kind) in enumerate(zip(problems, kinds)):
        ref = _highs(A, b, c)
        assert np.linalg.matrix_rank(A) == (ROWS - 1 if kind.startswith("rankdef") else ROWS)
        if kind in ("feasible", "rankdef"):
            assert ref.status == 0
            assert sol.status[k] == Status.OPTIMAL, (k, kind)
            assert sol.value[k] == pytest.approx(ref.fun, rel=1e-8, abs=1e-9), (k, kind)
            np.testing.assert_allclose(A @ sol.x[k], b, atol=1e-8 * (1 + np.abs(b).max()))
        else:
            assert ref.status == 2, (k, kind)
            assert sol.status[k] == Status.INFEASIBLE, (k, kind)
            y = sol.y[k]
            assert b @ y == pytest.approx(1.0, rel=1e-10)
            aty = A.T @ y
            assert aty.max() <= 1e-6 * max(1.0, np.abs(aty).max())


def test_rank_deficient_inconsistent_is_infeasible():
    rng = np.random.default_rng(8)
    problems = [_rank_deficient(rng, "inconsistent") for _ in range(BATCH)]
    for A, b, c in problems:
        assert _highs(A, b, c).status == 2
    sol = _solve(problems)
    assert np.all(sol.status == Status.INFEASIBLE), np.bincount(sol.status, minlength=3)
    for k, (A, b, c) in enumerate(problems):
        y = sol.y[k]
        assert b @ y == pytest.approx(1.0, rel=1e-10)
        aty = A.T @ y
        assert aty.max() <= 1e-6 * max(1.0, np.abs(aty).max())


def test_degenerate_zero_optimum():
    """A = [I -I], b = 0: the only feasible differences give optimum 0 at a highly degenerate
    vertex; also a problem with an all-zero column."""
    rng = np.random.default_rng(2)
    problems = []
    for _ in range(BATCH):
        A, b, c = _feasible(rng)
        problems.append((A, np.zeros(ROWS), np.abs(c)))  # x = 0 is the only optimum
    A, b, c = _feasible(rng)
    A[:, 3] = 0.0
    c[3] = 1.0
    problems[-1] = (A, b, c)
    sol = _solve(problems)
    for k, (A, b, c) in enumerate(problems):
        ref = _highs(A, b, c)
        assert sol.status[k] == Status.OPTIMAL
        assert sol.value[k] == pytest.approx(ref.fun, rel=1e-8, abs=1e-8)


def test_single_problem_and_several_fused():
    """``solve`` without vmap, and two LPs of different shapes in one fused loop."""
    rng = np.random.default_rng(3)
    A1, b1, c1 = _feasible(rng)
    A2, b2, c2 = _infeasible(rng, rows=3, cols=7)
    s1, s2 = jit(lambda l1, l2: solve(l1, l2))(LP(A1, b1, c1), LP(A2, b2, c2))
    assert int(s1.status) == Status.OPTIMAL and int(s2.status) == Status.INFEASIBLE
    assert float(s1.value) == pytest.approx(_highs(A1, b1, c1).fun, rel=1e-8)
    assert s1.x.shape == (COLS,) and s2.y.shape == (3,)


def test_solve_rejects_batched_problem():
    A, b, c = _feasible(np.random.default_rng(4))
    with pytest.raises(ValueError, match="vmap"):
        solve(LP(np.stack([A, A]), np.stack([b, b]), np.stack([c, c])))


def test_too_few_iterations_is_not_converged():
    A, b, c = _feasible(np.random.default_rng(5))
    # under jit: op by op, the solver's loop compiles a program per operation
    (sol,) = jit(lambda A, b, c: solve(LP(A, b, c), iterations=1))(A, b, c)
    assert int(sol.status) == Status.NOT_CONVERGED
    assert float(sol.value) == 0.0


_best_effort = jit(jax.vmap(lambda A, b, c, k: solve(LP(A, b, c), iterations=k, best_effort=True)[0]))


def test_best_effort_reports_the_best_iterate(problems):
    """``best_effort``: an LP unfinished after its budget reports its best iterate as
    ``APPROXIMATE`` (approaching HiGHS's optimum as the budget grows), infeasible ones are still
    certified, and with the full budget the results are those of a plain solve. The budget is a
    traced input: one program for every budget."""
    feasible, infeasible = problems
    A, b, c = (jnp.asarray(np.stack(x)) for x in zip(*(feasible + infeasible)))
    ref = np.array([_highs(*p).fun for p in feasible])
    k = len(feasible)
    errors = []
    for budget in (3, 6, 30):
        sol = jax.tree_util.tree_map(np.asarray, _best_effort(A, b, c, jnp.full(len(A), budget, jnp.int32)))
        assert set(sol.status[:k]) <= {Status.OPTIMAL, Status.APPROXIMATE}
        assert np.all(np.isfinite(sol.value)) and np.all(np.isfinite(sol.x))
        errors.append(np.max(np.abs(sol.value[:k] - ref) / (1 + np.abs(ref))))
        if budget == 3:
            assert np.sum(sol.status[:k] == Status.APPROXIMATE) > k // 2
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-7, errors
    assert np.all(sol.status[k:] == Status.INFEASIBLE)
    # (the plain solve in the program of the other tests' batches)
    plain = jax.tree_util.tree_map(lambda *a: np.concatenate(a), _solve(feasible), _solve(infeasible))
    np.testing.assert_array_equal(sol.status, plain.status)
    np.testing.assert_allclose(sol.value, plain.value, rtol=0, atol=1e-12)


def test_envelope_gradient_vs_highs_finite_differences():
    """d(optimal value) along random directions of (A, b, c): ``optimal_value``'s envelope-theorem
    gradient against central differences of HiGHS optima."""
    rng = np.random.default_rng(6)

    def value(A, b, c):
        lp = LP(A, b, c)
        (sol,) = solve(jax.lax.stop_gradient(lp))
        return optimal_value(lp, sol)

    grad = jit(jax.vmap(jax.grad(value, argnums=(0, 1, 2))))
    problems = [_feasible(rng) for _ in range(6)]
    A, b, c = (jnp.asarray(np.stack(x)) for x in zip(*problems))
    gA, gb, gc = (np.asarray(g) for g in grad(A, b, c))
    assert np.all(np.isfinite(gA)) and np.all(np.isfinite(gb)) and np.all(np.isfinite(gc))
    h = 1e-6
    checked = 0
    for k, (A, b, c) in enumerate(problems):
        for _ in range(3):
            dA, db, dc = rng.normal(size=A.shape), rng.normal(size=b.shape), rng.normal(size=c.shape)
            plus = _highs(A + h * dA, b + h * db, c + h * dc)
            minus = _highs(A - h * dA, b - h * db, c - h * dc)
            assert plus.status == 0 and minus.status == 0
            fd = (plus.fun - minus.fun) / (2 * h)
            ad = np.sum(gA[k] * dA) + gb[k] @ db + gc[k] @ dc
            assert ad == pytest.approx(fd, rel=1e-5, abs=1e-6)
            checked += 1
    assert checked == 18


def test_optimal_value_zero_unless_optimal():
    rng = np.random.default_rng(7)
    A, b, c = (jnp.asarray(x) for x in _infeasible(rng))
    lp = LP(A, b, c)
    (sol,) = jit(solve)(lp)  # under jit: see test_too_few_iterations_is_not_converged
    assert int(sol.status) == Status.INFEASIBLE
    assert float(optimal_value(lp, sol)) == 0.0
    g = jit(jax.grad(lambda A, sol: optimal_value(LP(A, b, c), sol)))(A, sol)
    assert np.all(np.asarray(g) == 0.0)


def _lock_step(fn, block=64):
    """``vmap(fn)`` over blocks of ``block`` < ``STREAM_MIN`` problems: solved in lock step."""

    def run(*args):
        n = args[0].shape[0]
        split = jax.tree_util.tree_map(lambda a: a.reshape((n // block, block) + a.shape[1:]), args)
        out = jax.lax.map(lambda xs: jax.vmap(fn)(*xs), split)
        return jax.tree_util.tree_map(lambda a: a.reshape((n,) + a.shape[2:]), out)

    return run


def _compare(streamed, locked, lanes_active=None):
    keep = slice(None) if lanes_active is None else lanes_active
    np.testing.assert_array_equal(streamed.status[keep], locked.status[keep])
    # A residual at the tolerance can meet it an iteration earlier in one vector width than in
    # another (seen once in 512 warm-started problems, natively and under
    # XLA_FLAGS=--xla_cpu_max_isa=AVX2); that problem's solution is then an iteration apart, within
    # the solver's tolerance.
    gap = np.abs(streamed.iterations[keep].astype(int) - locked.iterations[keep])
    assert gap.max() <= 1 and np.mean(gap > 0) <= 0.01
    for a, b in ((streamed.x, locked.x), (streamed.y, locked.y), (streamed.value, locked.value)):
        np.testing.assert_allclose(a[keep], b[keep], rtol=1e-7, atol=1e-7)


def _streamed_and_locked(cases):
    """``(streamed, locked)``: for each case ``(build, args)``, ``build(batch)(*args)`` with ``batch``
    ``jax.vmap`` (streamed) and :func:`_lock_step`, all cases in one program each way: two
    compilations instead of two per case, which cost more than the programs' size (four solves:
    30 s in eight programs, 10 s in two)."""
    builds = [build for build, _ in cases]

    def run(batch):
        out = jit(lambda args: [build(batch)(*a) for build, a in zip(builds, args)])([a for _, a in cases])
        return jax.tree_util.tree_map(np.asarray, out)

    return run(jax.vmap), run(_lock_step)


def _solved(**kwargs):
    """``build`` of a case (:func:`_streamed_and_locked`): ``batch`` of a solve with ``kwargs``."""
    return lambda batch: batch(lambda A, b, c, *rest: solve(LP(A, b, c), **{
        k: (v(*rest) if callable(v) else v) for k, v in kwargs.items()})[0])


def test_streamed_batch_equals_lock_step():
    """A vmapped solve of ``STREAM_MIN`` or more problems streams them through ``LANES`` lanes
    (``_lp._stream``): every problem gets the iterations, status and solution it gets in lock step
    (feasible, infeasible, inconsistent; full and short budgets, best effort, a traced budget, warm
    starts with per-problem weights, skipped problems, float32 restarts), and the envelope gradient."""
    from grasp_jax.lp import _stream as _lp

    rng = np.random.default_rng(11)
    n = _lp.STREAM_MIN
    kinds = [_feasible(rng) if k % 3 else _infeasible(rng) for k in range(n - 8)]
    kinds += [_rank_deficient(rng, "inconsistent") for _ in range(8)]
    A, b, c = (jnp.asarray(np.stack(x)) for x in zip(*kinds))
    near = A + 1e-3 * jnp.asarray(rng.normal(size=A.shape))  # (for the warm starts below)
    skip = jnp.asarray(rng.uniform(size=n) < 0.5)
    # (the full solve in programs of its own: the warm starts below start from its solution, the
    # same to the last bit as before the cases shared programs)
    (full_streamed,), (full_locked,) = _streamed_and_locked([(_solved(), (A, b, c))])
    _compare(full_streamed, full_locked)
    streamed, locked = _streamed_and_locked([
        (_solved(iterations=4), (A, b, c)),
        (_solved(iterations=4, best_effort=True), (A, b, c)),
        (_solved(iterations=jnp.int32(5)), (A, b, c)),
        (_solved(skip=lambda k: k), (A, b, c, skip)),
    ])
    (short, _, _, skipped) = streamed
    for k, (s, l) in enumerate(zip(streamed, locked)):
        _compare(s, l, ~np.asarray(skip) if k == 3 else None)
    statuses = full_streamed.status
    assert {Status.OPTIMAL, Status.INFEASIBLE} <= set(statuses.tolist())
    assert np.any(short.status == Status.NOT_CONVERGED)
    assert np.all(skipped.iterations[np.asarray(skip)] == 0)
    # warm from a nearby problem's solution, weight 0 for every third problem (the full solve's,
    # streamed)
    first = jax.tree_util.tree_map(jnp.asarray, full_streamed)
    point = jax.vmap(lambda A, b, c, s: warm_point(LP(A, b, c), s))(A, b, c, first)
    weight = jnp.where(jnp.arange(n) % 3 == 0, 0.0, 0.99)
    warm = _solved(warm=lambda x, y, s, w: ((x, y, s),), weight=lambda x, y, s, w: w)
    (warm_streamed,), (warm_locked,) = _streamed_and_locked([(warm, (near, b, c, *point, weight))])
    _compare(warm_streamed, warm_locked)
    # float32 (restarts from other starting points after a spent budget); the envelope gradient of
    # the optimal values in c, streamed and in lock step
    f32 = tuple(a.astype(jnp.float32) for a in (A, b, c))
    value = lambda A, b, c: optimal_value(LP(A, b, c), solve(jax.lax.stop_gradient(LP(A, b, c)))[0])  # noqa: E731

    def gradient(batch):
        return lambda A, b, c: jax.grad(lambda c: jnp.sum(batch(value)(A, b, c)))(c)

    (streamed32, grad_streamed), (locked32, grad_locked) = _streamed_and_locked(
        [(_solved(), f32), (gradient, (A, b, c))])
    # float32: the same statuses but for round-off at the tolerance
    assert np.mean(streamed32.status == locked32.status) >= 0.99
    # (the gradient is the solution x: where a problem ended an iteration apart, which
    # ``_compare`` allows on 1% of them, the two are two iterates within the solver's
    # tolerance of 1e-9; seen under XLA_FLAGS=--xla_cpu_max_isa=AVX2, one problem of 512, 2.5e-10
    # apart, 1.8e-11 elsewhere)
    same = full_streamed.iterations == full_locked.iterations
    np.testing.assert_allclose(grad_streamed[same], grad_locked[same], rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(grad_streamed[~same], grad_locked[~same], rtol=1e-9, atol=1e-9)
