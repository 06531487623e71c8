"""The LP in standard form, its solution, its statuses, and the optimal value's gradient."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._status import StatusEnum


class Status(StatusEnum):
    """Outcome of one LP (stored per problem as ``int8``)."""

    OPTIMAL = 0, "optimal"
    INFEASIBLE = 1, "infeasible (certified by the homogeneous model)"
    NOT_CONVERGED = 2, "not converged in the iteration budget; values are not reliable"
    #: Only with ``solve(..., best_effort=True)``: unfinished after the budget, and ``x, y`` are
    #: its best iterate (an approximate optimum, good for a gradient step, not for a verdict).
    APPROXIMATE = 3, "not converged in the iteration budget; the best iterate is reported"
    #: Set by the caller of :func:`solve`, never by it: unfinished after the full budget, but the
    #: dual of its best iterate bounds the optimum by weak duality, which settles the question the
    #: LP was solved for (grasp_jax: the quality LP's ``delta* < 0``, not in equilibrium, the
    #: reported value is that bound; the torque LP's ``l* <= 0``, no positive span, reported 0).
    BOUNDED = 4, "not converged in the iteration budget, but a dual bound settles the verdict"


class LP(NamedTuple):
    """One LP in standard form. ``A: (rows, cols)``, ``b: (rows,)``, ``c: (cols,)``."""

    A: jax.Array
    b: jax.Array
    c: jax.Array


class LPSolution(NamedTuple):
    """Result of :func:`solve` for one LP.

    Attributes:
        x: ``(cols,)`` primal solution (meaningful when ``status == OPTIMAL``; when
            ``NOT_CONVERGED``, the best iterate's).
        y: ``(rows,)`` dual solution; when ``status == INFEASIBLE`` a Farkas certificate scaled so
            that ``b . y = 1`` and ``A^T y <= 0`` (up to tolerance); when ``NOT_CONVERGED`` the
            dual part of the best iterate (for a weak-duality bound, not for a value).
        value: ``c . x`` (0 unless optimal).
        status: ``int8`` :class:`Status`.
        iterations: iterations actually taken before freezing.
        residual: largest relative primal/dual residual and gap at the end.
    """

    x: jax.Array
    y: jax.Array
    value: jax.Array
    status: jax.Array
    iterations: jax.Array
    residual: jax.Array


def optimal_value(lp: LP, solution: LPSolution) -> jax.Array:
    """``c . x*`` with derivatives from the envelope theorem.

    With ``x*, y*`` held fixed, ``c.x* - y*.(A x* - b)`` equals the optimal value and its
    derivative in ``(A, b, c)`` is ``dc.x* - y*.(dA x* - db)``, the derivative of the optimal
    value wherever the optimum is unique. No iteration is differentiated. Zero where the LP is not
    optimal (or ``APPROXIMATE``: then the same expression at the best iterate).
    """
    x = jax.lax.stop_gradient(solution.x)
    y = jax.lax.stop_gradient(solution.y)
    value = lp.c @ x - y @ (lp.A @ x - lp.b)
    return jnp.where(has_value(solution), value, 0.0)


def has_value(solution: LPSolution) -> jax.Array:
    """Whether ``solution`` carries an optimum: ``OPTIMAL``, or ``APPROXIMATE`` (best effort)."""
    return (solution.status == Status.OPTIMAL) | (solution.status == Status.APPROXIMATE)
