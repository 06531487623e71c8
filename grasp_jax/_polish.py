"""float32: the quality LP of a grasp whose torques about ``c_1`` lie in a half-space, solved
again in a reduced form and moved to a certified vertex (``lp.polish``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._cones import safe_normalize
from .lp import LP, LPSolution, as_solution, polish, stacked

#: A certified torque LP margin ``|l*|`` at most this (float32 rounding leaves ~1e-8 on exact zeros)
#: means the torques lie in the closed half-space ``u . tau >= 0`` of its dual direction ``u`` and
#: some on its boundary plane. (``l* < -HALF_SPACE``: all of them strictly inside an open
#: half-space, which forces ``delta* = -1`` exactly, :func:`open_half_space`.)
HALF_SPACE = 1e-7
#: Columns with ``u . tau_j`` above this fraction of ``max |tau_j|`` are off the plane ``u . tau = 0``
#: (exactly: the torques of a box grasp's contacts on one face; the others are ~1e-8).
OFF_PLANE = 1e-5
#: Simplex pivots of the reduced quality LP, which starts from nothing (``x = y = 0``).
REDUCED_PIVOTS = 64


def plane_basis(u: jax.Array) -> jax.Array:
    """``(3, 3)`` orthonormal rows, the first ``u`` (unit)."""
    a = jnp.eye(3, dtype=u.dtype)[jnp.argmin(jnp.abs(u))]
    v1 = safe_normalize(a - (a @ u) * u)
    return jnp.stack([u, v1, jnp.cross(u, v1)])


def half_space_quality_lp(q_lp: LP, u: jax.Array) -> tuple[LP, jax.Array]:
    """The 3D quality LP (one zero column appended) when every torque satisfies ``u . tau >= 0``.

    Then ``sum a_ij tau_ij = 0`` forces ``a_ij = 0`` on every column off the plane ``u . tau = 0``,
    and the LP is degenerate: its optimal bases have condition ~1e5 in float32 and are not
    certified (``lp._crossover.CONDITION``). Here those columns are removed (zeroed), the torque rows
    are rotated to ``(u, v1, v2)`` and the ``u`` row, now empty up to rounding, fixes the appended
    column at 1. Returns ``(lp, rotation)``.
    """
    A, b, c = q_lp
    R = plane_basis(u)
    tau = A[3:6]
    off = (u @ tau) > OFF_PLANE * jnp.max(jnp.abs(tau), axis=0)
    rows = jnp.concatenate([A[:3], (R @ tau)[1:], A[6:]])
    rows = jnp.where(off[None, :], 0.0, rows)
    r, N = A.shape
    A = jnp.concatenate([rows[:3], jnp.zeros((1, N), A.dtype), rows[3:]])
    A = jnp.concatenate([A, jnp.eye(r, 1, -3, dtype=A.dtype)], axis=1)  # the unit column of row 3
    b = b.at[3:6].set(R @ b[3:6]).at[3].set(1.0)
    c = jnp.concatenate([jnp.where(off, 0.0, c), jnp.zeros(1, c.dtype)])
    return LP(A, b, c), R


def original_dual(y: jax.Array, R: jax.Array) -> jax.Array:
    """The dual vector of a :func:`half_space_quality_lp` in the rows of the quality LP: torque
    rows rotated back, 0 on the ``u`` row. Its reduced costs are those of the reduced LP on the
    columns it kept; the removed ones are zero at every feasible point. (A ``u`` entry that also
    prices them reaches 1e4 where ``u . tau_j`` is small, and the envelope value ``c.x -
    y.(A x - b)`` then carried 1e-4 of the kept columns' rounding.)"""
    return jnp.concatenate([y[:3], R.T @ y[3:6].at[0].set(0.0), y[6:]])


def open_half_space(t_polished) -> jax.Array:
    """float32: whether the torque LP's certified vertex proves ``l* < -HALF_SPACE``, i.e. every
    torque about ``c_1`` strictly inside an open half-space ``u . tau > 0``. Then no combination
    of the other contacts' columns has zero torque, only contact 1's edges balance, and
    ``delta* = -1`` exactly, whatever the quality LP's float32 solve says: on such a grasp a few
    roundoffs in the data make the torques span (the torque margin -2.3e-7 of one cylinder-side
    grasp, where float32's certified quality vertex read ``delta = 0.158``; in float64 moving the
    inputs by 1e-8 flips its ``Q`` between 0 and 0.135). ``t_polished``: :func:`polish`'s triple."""
    sol, certified, _ = t_polished
    K = sol.x.shape[0] - 1
    return certified & (1.0 / K - sol.x[-1] < -HALF_SPACE)


def polish_exact(q_lp: LP, t_lp: LP, q_sol: LPSolution, t_sol: LPSolution, pivots: tuple, full):
    """:func:`polish` of the quality and torque LPs of a 3D exact evaluation (one :func:`stacked`
    crossover), then a second round through the same compiled crossover (a loop of two rounds, the
    second only where needed) for a grasp whose torque LP certifies ``|l*| <=`` :data:`HALF_SPACE`:
    the quality LP again, in the reduced form of :func:`half_space_quality_lp`, from nothing. On
    such a grasp round one's vertex is never taken, even certified: the full quality LP is
    ill-posed there (its optimal dual is ~1e4-1e5, against ~2-5 elsewhere, so a few roundoffs in
    its data move ``delta*`` by up to 4e-3 and the vertex the crossover reaches depends on the
    CPU's rounding order). Without a certified reduced vertex the quality LP stays uncertified.
    ``t_sol``: the torque LP's interior-point solution, or zeros (``quality_one``: the crossover
    then starts from nothing). ``full``: whether the quality LP had the full budget (may be
    traced); then a full quality LP that round one does not certify runs again in round two, from
    the interior point's dual alone. Returns :func:`polish`'s triples.

    Such grasps are most of float32's rare ``|Q32 - Q64| > 1e-4`` (``experiments/float32_accuracy.py``);
    the reduced LP's vertex is certified on them and within 1e-6 of float64's Q.
    """
    if all(isinstance(k, int) and not k for k in pivots):  # float64: no crossover
        return [polish(q_lp, q_sol, 0), polish(t_lp, t_sol, 0)]
    q_lp, t_lp = jax.lax.stop_gradient(q_lp), jax.lax.stop_gradient(t_lp)
    r, N = q_lp.A.shape
    K = t_lp.A.shape[1] - 1
    dt = q_lp.A.dtype
    wide = LP(jnp.pad(q_lp.A, ((0, 0), (0, 1))), q_lp.b, jnp.pad(q_lp.c, (0, 1)))
    start = (wide, jnp.pad(q_sol.x, (0, 1)), q_sol.y)
    budget = jnp.stack([jnp.asarray(k, jnp.int32) for k in pivots])

    def body(carry):
        k, (lp, x, y), budget, best, half, need = carry
        (xq, yq, cq), (xt, yt, ct) = stacked((lp, t_lp), (x, t_sol.x), (y, t_sol.y), budget)
        first = k == 0
        # Round two keeps round one's torque vertex: that LP had no second pivot budget.
        xt, yt, ct = (jnp.where(first, new, old) for new, old in zip((xt, yt, ct), best[3:]))
        reduced, R = half_space_quality_lp(q_lp, safe_normalize(-yt[:3]))
        # On such a grasp round one's vertex, certified or not, is never the answer: the LP is
        # ill-posed (a few roundoffs in its data move delta* by 1e-3) and the vertex found
        # depends on the CPU's rounding order. Only the reduced LP's vertex is taken; without it
        # the value stays uncertified.
        half = jnp.where(first, ct & (jnp.abs(1.0 / K - xt[-1]) <= HALF_SPACE), half)  # l* ~ 0
        # After the full budget, a full quality LP whose vertex round one did not certify runs
        # again from the interior point's dual alone (x = 0): its primal iterate can lead the
        # initial basis astray.
        retry = first & ~cq & ~half & full
        cq = jnp.where(first, cq & ~half, cq)
        take = first | cq
        xq = jnp.where(take, xq, best[0])
        back = jnp.where(half, original_dual(yq, R), yq)
        yq = jnp.where(first, yq, jnp.where(cq, back, best[1]))
        cq = jnp.where(take, cq, best[2])
        need = first & (half | retry)
        lp = jax.tree_util.tree_map(lambda a, b: jnp.where(half, a, b), reduced, wide)
        start_y = jnp.where(half, 0.0, q_sol.y)
        again = jnp.asarray([REDUCED_PIVOTS, 0], jnp.int32)
        return k + 1, (lp, jnp.zeros(N + 1, dt), start_y), again, (xq, yq, cq, xt, yt, ct), half, need

    best = (start[1], start[2], jnp.zeros((), bool), t_sol.x, t_sol.y, jnp.zeros((), bool))
    carry = (jnp.zeros((), jnp.int32), start, budget, best, jnp.zeros((), bool), jnp.ones((), bool))
    _, _, _, (xq, yq, cq, xt, yt, ct), _, _ = jax.lax.while_loop(lambda c: c[-1], body, carry)
    return [as_solution(q_lp, q_sol, xq[:N], yq, cq), as_solution(t_lp, t_sol, xt, yt, ct)]
