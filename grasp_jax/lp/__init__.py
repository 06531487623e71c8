"""A small dense LP solver in pure JAX, written for one problem and batched by ``jax.vmap``.

``minimize c . x  subject to  A x = b, x >= 0`` by a homogeneous self-dual interior-point method
(``_ipm``: the step; ``_loop``: the iterations; ``_stream``: the batching rule; ``_solve``: the
entry point), the envelope-theorem gradient of the optimal value (``_problem``), and a crossover
to a certified vertex for float32 (``_crossover``).
"""

from ._crossover import SENSITIVE as SENSITIVE
from ._crossover import as_solution as as_solution
from ._crossover import crossover as crossover
from ._crossover import polish as polish
from ._crossover import sensitivity as sensitivity
from ._crossover import stacked as stacked
from ._ipm import warm_point as warm_point
from ._ipm import warm_weight as warm_weight
from ._problem import LP as LP
from ._problem import LPSolution as LPSolution
from ._problem import Status as Status
from ._problem import has_value as has_value
from ._problem import optimal_value as optimal_value
from ._solve import solve as solve
from ._stream import LANES as LANES
from ._stream import STREAM_MIN as STREAM_MIN

__all__ = ["LP", "LPSolution", "Status", "solve", "optimal_value", "has_value", "warm_point", "warm_weight",
           "crossover", "polish", "sensitivity", "stacked", "as_solution", "SENSITIVE", "STREAM_MIN", "LANES"]
