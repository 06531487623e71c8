"""``jit`` for the suite's own large programs, compiled for a short compile (test helper).

Compiling XLA programs is most of the suite's time. These programs are compiled with LLVM's
optimization level 0 and XLA's classic CPU emitters (``xla_cpu_use_fusion_emitters`` off), which
compile each fused kernel faster: ``tests/test_closure.py`` and ``tests/test_contact.py`` took 244
CPU-s instead of 302 with the fusion emitters (2026-12-08), and level 0 roughly halves a large
program's compile against XLA's default. The options change how XLA generates machine code, not
what the library's JAX code computes; only the last bits of a value may differ, as between two XLA
versions. The library's own chunk programs, which this helper does not touch, are compiled as a
user's are (``grasp_jax._batch.COMPILER_OPTIONS``).

``GRASP_JAX_TEST_OPT=default`` compiles these programs with XLA's default options instead (to
check that a result does not depend on them); ``GRASP_JAX_TEST_OPT=<n>`` with level ``n``.
"""

from __future__ import annotations

import os

import jax


def _options() -> dict:
    level = os.environ.get("GRASP_JAX_TEST_OPT", "0").strip().lower()
    if level in ("", "default", "none"):
        return {}
    return {"xla_backend_optimization_level": int(level), "xla_cpu_use_fusion_emitters": False}


#: Compiler options of every program made by :func:`jit`.
COMPILER_OPTIONS = _options()
#: ... with XLA's fusion emitters instead (``jit(fn, options=FUSION_EMITTERS)``), for a file that
#: compares two of its programs bit for bit (``tests/test_lp.py``: a warm start against a cold
#: one): two programs that the classic emitters fuse differently may round an ulp apart.
FUSION_EMITTERS = {k: v for k, v in COMPILER_OPTIONS.items() if k != "xla_cpu_use_fusion_emitters"}


class jit:  # noqa: N801 - used like jax.jit
    """``jax.jit(fn)`` compiled with :data:`COMPILER_OPTIONS` (or ``options``), once per input signature.

    Arguments are arrays (or pytrees of arrays); the compiled programs are kept per tree structure,
    shape and dtype of the leaves and per x64 mode, and JAX's persistent cache (``conftest.py``)
    keeps them between runs as it keeps ``jax.jit``'s.
    """

    def __init__(self, fn, options: dict | None = None):
        self._jitted = jax.jit(fn)
        self._options = COMPILER_OPTIONS if options is None else options
        self._compiled: dict = {}

    def _key(self, args):
        leaves, tree = jax.tree_util.tree_flatten(args)
        return tree, tuple(jax.typeof(x) for x in leaves), jax.config.jax_enable_x64

    def __call__(self, *args):
        key = self._key(args)
        compiled = self._compiled.get(key)
        if compiled is None:
            compiled = self._jitted.lower(*args).compile(compiler_options=self._options)
            self._compiled[key] = compiled
        return compiled(*args)
