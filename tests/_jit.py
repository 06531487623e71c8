"""``jit`` for the suite's own large programs, compiled with fewer LLVM optimization passes (test helper).

Compiling XLA programs is most of the suite's time, and most of a large program's compile time on
a CPU is LLVM optimizing the generated code: ``xla_backend_optimization_level`` 0 instead of
XLA's default roughly halves it (the fused evaluate + min_weight + paper program of
``test_closure.py``, 4 fingers: 10.5 s against 19 s of CPU) while the programs run in about the
same time on the suite's small batches. The level changes how the machine code is optimized, not
what it computes: the library's JAX code, its HLO and XLA's HLO passes are the same; only the last
bits of a value may differ, as between any two XLA versions (the library's own chunk programs, which
this helper does not touch, use level 1: ``grasp_jax._batch.COMPILER_OPTIONS``).

``GRASP_JAX_TEST_OPT=default`` compiles these programs with XLA's default options instead (to
check that a result does not depend on the level); ``GRASP_JAX_TEST_OPT=<n>`` with level ``n``.
"""

from __future__ import annotations

import os

import jax


def _options() -> dict:
    level = os.environ.get("GRASP_JAX_TEST_OPT", "0").strip().lower()
    if level in ("", "default", "none"):
        return {}
    return {"xla_backend_optimization_level": int(level)}


#: Compiler options of every program made by :func:`jit`.
COMPILER_OPTIONS = _options()


class jit:  # noqa: N801 - used like jax.jit
    """``jax.jit(fn)`` compiled with :data:`COMPILER_OPTIONS`, once per input signature.

    Arguments are arrays (or pytrees of arrays); the compiled programs are kept per tree structure,
    shape and dtype of the leaves and per x64 mode, and JAX's persistent cache (``conftest.py``)
    keeps them between runs as it keeps ``jax.jit``'s.
    """

    def __init__(self, fn):
        self._jitted = jax.jit(fn)
        self._compiled: dict = {}

    def _key(self, args):
        leaves, tree = jax.tree_util.tree_flatten(args)
        return tree, tuple(jax.typeof(x) for x in leaves), jax.config.jax_enable_x64

    def __call__(self, *args):
        key = self._key(args)
        compiled = self._compiled.get(key)
        if compiled is None:
            compiled = self._jitted.lower(*args).compile(compiler_options=COMPILER_OPTIONS)
            self._compiled[key] = compiled
        return compiled(*args)
