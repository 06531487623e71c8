"""The result container of :func:`grasp_jax.evaluate`."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .lp import Status


def _traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in xs)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GraspEvaluation:
    """Everything :func:`grasp_jax.evaluate` knows about a batch of grasps.

    Every field has the leading batch shape ``B`` of the input (``()`` for one grasp).

    Attributes:
        force_closure: ``B`` bool. Proposition 2 with the chosen torque test.
        quality: ``B`` float. The paper's Q (eq. 23), ``0.0`` where the grasp is not in equilibrium.
        equilibrium: ``B`` bool. Eq. (17) / (22) has a solution with ``delta > 0``
            (Proposition 1 at ``c_1``).
        torque_span: ``B`` bool. The torques of contacts 2..n about ``c_1`` positively span R^3
            (R in 2D) (Proposition 2(2); eq. 15 / 21 with ``torque_test="paper"``).
        delta: ``B`` float. Signed optimum of the always-feasible quality LP: ``Q`` where positive,
            and a continuous measure of how far from equilibrium the grasp is where not (where
            ``quality_status`` is ``BOUNDED``, an upper bound on it, below 0).
        torque_margin: ``B`` float. Margin of the torque test: ``l*`` of the torque min-weight LP
            (exact, 3D), the smaller of the largest positive and negative torques over the grasp size
            (2D), or the weakest eq. (15) slack (``"paper"``, 3D).
        certificate: ``B + (3,)`` in 2D, ``B + (6,)`` in 3D. For a grasp that is not force-closure, a
            unit wrench ``u = (force, torque about the origin)`` with ``u . w >= 0`` for every
            primitive wrench ``w``: no contact force can push the object along ``-u``, so an external
            wrench along ``+u`` cannot be resisted. Zero for a force-closure grasp.
        quality_status: ``B`` int8 :class:`grasp_jax.Status` of the quality LP: ``OPTIMAL``,
            ``NOT_CONVERGED``, or ``BOUNDED`` (unfinished, but weak duality proves ``delta* < 0``:
            not in equilibrium, ``Q = 0`` exactly; seen in float32 only).
        torque_status: ``B`` int8 status of the torque LP (``OPTIMAL`` where none was needed;
            ``BOUNDED``: unfinished, but a direction ``u`` with ``u . tau >= 0`` for every torque
            proves that they do not span, margin reported 0; float32 only).
        iterations: ``B`` int32. Interior-point iterations the quality LP took; 0 where it was not
            solved (3D, exact torque test, float64: the torque LP proved the torques of contacts 2..n
            strictly inside a half-space, so that ``delta = -1`` exactly, see ``_closure.torque_stage``).
    """

    force_closure: jax.Array
    quality: jax.Array
    equilibrium: jax.Array
    torque_span: jax.Array
    delta: jax.Array
    torque_margin: jax.Array
    certificate: jax.Array
    quality_status: jax.Array
    torque_status: jax.Array
    iterations: jax.Array

    @property
    def converged(self):
        """``B`` bool: every LP of the grasp ended optimal or certified (status not NOT_CONVERGED).
        A NumPy array for concrete results, a JAX array under a transformation."""
        unfinished = Status.NOT_CONVERGED
        if _traced(self.quality_status, self.torque_status):
            return (self.quality_status != unfinished) & (self.torque_status != unfinished)
        return (np.asarray(self.quality_status) != unfinished) & (np.asarray(self.torque_status) != unfinished)

    def __repr__(self) -> str:
        """A short summary, e.g. ``GraspEvaluation(batch=(1000,), force_closure 61.2%, Q median
        0.31 where force-closure, dtype float64)``; the fields themselves are attributes."""
        shape = tuple(np.shape(self.force_closure))
        dtype = np.dtype(self.quality.dtype).name
        if _traced(*(getattr(self, f.name) for f in dataclasses.fields(self))):
            return f"GraspEvaluation(batch={shape}, traced, dtype {dtype})"
        fc = np.asarray(self.force_closure)
        parts = [f"batch={shape}"]
        if fc.size:
            parts.append(f"force_closure {100.0 * fc.mean():.1f}%")
            q = np.asarray(self.quality)[fc]
            if q.size:
                parts.append(f"Q median {np.median(q):.3g} where force-closure")
            bad = int(np.sum(~self.converged))
            if bad:
                parts.append(f"{bad} not converged")
        parts.append(f"dtype {dtype}")
        return f"GraspEvaluation({', '.join(parts)})"

    def __getitem__(self, index) -> "GraspEvaluation":
        """Index every field with the same batch index."""
        return jax.tree_util.tree_map(lambda a: a[index], self)

    def __len__(self) -> int:
        return len(self.force_closure)
