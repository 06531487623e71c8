"""The result container of :func:`grasp_jax.evaluate`."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np


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
            and a continuous measure of how far from equilibrium the grasp is where not.
        torque_margin: ``B`` float. Margin of the torque test: ``l*`` of the torque min-weight LP
            (exact, 3D), the smaller of the largest positive and negative torques over the grasp size
            (2D), or the weakest eq. (15) slack (``"paper"``, 3D).
        certificate: ``B + (3,)`` in 2D, ``B + (6,)`` in 3D. For a grasp that is not force-closure, a
            unit wrench ``u = (force, torque about the origin)`` with ``u . w >= 0`` for every
            primitive wrench ``w``: no contact force can push the object along ``-u``, so an external
            wrench along ``+u`` cannot be resisted. Zero for a force-closure grasp.
        quality_status: ``B`` int8 :class:`grasp_jax.Status` of the quality LP.
        torque_status: ``B`` int8 status of the torque LP (``OPTIMAL`` where none was needed).
        iterations: ``B`` int32. Interior-point iterations the quality LP took.
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
        """``B`` bool: every LP of the grasp ended optimal or certified (status not NOT_CONVERGED)."""
        return (np.asarray(self.quality_status) != 2) & (np.asarray(self.torque_status) != 2)

    def __getitem__(self, index) -> "GraspEvaluation":
        """Index every field with the same batch index."""
        return jax.tree_util.tree_map(lambda a: a[index], self)

    def __len__(self) -> int:
        return len(self.force_closure)
