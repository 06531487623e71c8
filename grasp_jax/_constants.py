"""Every tolerance and default of grasp_jax, in one place.

Tolerances depend on the floating-point type: use :func:`tolerances` with the dtype of the data.
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: Default number of edges of a linearized 3D friction cone (the paper uses 25).
DEFAULT_NUM_EDGES = 8

#: Interior-point iterations, chosen from the number of LP variables (see ``SOLVER.md``: 15 were
#: enough for 33 variables, 25 for about 200).  Problems that converge earlier are frozen.
def default_iterations(num_vars: int) -> int:
    """Iteration budget of the interior-point method for an LP with ``num_vars`` columns.

    The slowest of 100,000 random 4-finger quality LPs (33 columns) took 23 iterations."""
    return 30 if num_vars <= 64 else 40


def first_pass_iterations(num_vars: int) -> int:
    """Budget of the fast first pass of a chunk (``_batch.Retry``): most problems converge in
    it; the rest are solved again with :func:`default_iterations`.

    Chosen by CPU time per grasp of ``evaluate`` on 100k ellipsoid grasps (2-core CPU): 10 for
    n = 3, 4 with 8 edges (25, 33 columns; 12 cost 6% more), 12 for n = 7 with 8 edges and n = 3
    with 25 (57, 76), 14 for n = 4 with 25 (101), 16 for n = 7 with 25 (176)."""
    if num_vars <= 40:
        return 10
    if num_vars <= 80:
        return 12
    return 14 if num_vars <= 128 else 16


@dataclasses.dataclass(frozen=True)
class Tolerances:
    """Numerical thresholds for one floating-point type.

    Attributes:
        lp: relative residual and gap at which the interior-point method stops (per problem).
        margin: a margin (``delta*`` of the quality LP, ``l*`` of a min-weight LP, both scale free)
            must exceed this to count as strictly positive. Grasps within ``margin`` of the boundary
            of force-closure are *marginal*; their verdict is decided by this one number.
        rank: relative eigenvalue below which a Gram matrix of wrenches counts as rank deficient.
        pivot: relative Cholesky pivot below which a direction counts as degenerate.
        tiny: lengths below this are treated as zero (normalization guards).
        refine: steps of iterative refinement of each interior-point direction (``lp._step``).
        near: after the full budget, an unfinished LP whose best iterate is within ``near`` times
            ``lp`` counts as optimal there; so does an ill-posed one (tau, kappa -> 0) at the end.
        step: fraction of the step to the boundary the interior-point method takes.
        restarts: with the full budget, problems left unfinished start again from
            ``x = s = factor`` for each factor in turn (``lp.solve``).
        crossover: most simplex pivots from the interior-point solution to a certified optimal
            vertex (``_crossover``), with the full budget; 0: none.
        crossover_short: the same after a short budget (the first pass of ``_batch.Retry``), where
            a quality LP whose value no vertex certifies is left for the retry pass. Every problem
            of a vmapped block waits for its slowest: 32 pivots in the first pass cost 44% of the
            float32 throughput (box, 4 fingers, 8 edges). After the full budget 64: with 32, a
            sphere grasp with 25 edges stopped one pivot short of its optimal vertex.
    """

    lp: float
    margin: float
    rank: float
    pivot: float
    tiny: float
    refine: int = 0
    near: float = 100.0
    step: float = 0.999
    restarts: tuple = ()
    crossover: int = 0
    crossover_short: int = 0


_F64 = Tolerances(lp=1e-9, margin=1e-7, rank=1e-10, pivot=1e-13, tiny=1e-30)
#: float32 (checked by ``experiments/float32_accuracy.py``): the interior-point method aims at
#: 1e-6 and refines every direction once; after the full budget the best iterate within 100x counts
#: as optimal, as in float64, and LPs still unfinished start again from the other points of
#: ``restarts`` in turn (a stalled trajectory is rounding, not the problem). A margin must exceed
#: 2e-5, so that verdicts of grasps whose margins are clear of 1e-4 match float64's. A crossover to
#: a certified vertex (``lp._crossover``) follows.
_F32 = Tolerances(lp=1e-6, margin=2e-5, rank=1e-5, pivot=1e-6, tiny=1e-30, refine=1,
                  restarts=(3.0, 0.3, 1.7, 0.6, 10.0, 0.1), crossover=64, crossover_short=12)


def tolerances(dtype) -> Tolerances:
    """Thresholds for ``dtype`` (float64 or float32)."""
    return _F64 if np.dtype(dtype) == np.float64 else _F32
