"""Robust labels written beside a stream's nominal scores (``grasp-jax sample / score --robust N``).

:class:`RobustLabels` holds the settings and computes the columns of one chunk: free contacts by
:func:`grasp_jax.robust`, parallel-jaw grasps under noise that moves contacts by
:func:`grasp_jax.grippers.robust_jaws` (the closing line cast again at every perturbed pose).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from typing import ClassVar

from ._robust import robust
from .grippers import ParallelJaw, robust_jaws


@dataclasses.dataclass(frozen=True)
class RobustLabels:
    """Robust labels written beside the nominal scores (``grasp-jax sample / score --robust N``):
    :func:`grasp_jax.robust` of every chunk, with the same draws for every chunk (one key), so the
    labels do not depend on the chunk size. Parallel-jaw grasps (chunks with jaw poses) under noise
    that moves contacts are labelled by :func:`grasp_jax.grippers.robust_jaws` instead: the closing
    line cast again at every perturbed pose (the metadata's ``robust`` says ``"jaws": "recast"``).

    Attributes:
        noise: a :class:`grasp_jax.Noise`.
        samples: perturbations per grasp (>= 2).
        seed: the key's seed (``jax.random.key(seed)``).
        quantile: of ``q_low`` and ``margin_low``.
        margin: also the min-weight margin columns.
        obj: the object, where the noise moves contacts.
    """

    noise: object
    samples: int = 100
    seed: int = 0
    quantile: float = 0.1
    margin: bool = True
    obj: object = None

    #: RobustResult field -> result file column.
    COLUMNS: ClassVar[dict] = {"p_fc": "p_fc", "p_fc_se": "p_fc_se", "q_mean": "q_mean", "q_mean_se": "q_mean_se",
               "q_low": "q_low", "margin_mean": "margin_mean", "margin_mean_se": "margin_mean_se",
               "margin_low": "margin_low", "unconverged": "robust_unconverged"}

    def fields(self) -> tuple[str, ...]:
        """The result file columns this adds."""
        return tuple(c for f, c in self.COLUMNS.items() if self.margin or not f.startswith("margin"))

    def to_dict(self) -> dict:
        """The settings, for a result file's metadata (``robust``)."""
        return {"samples": int(self.samples), "seed": int(self.seed), "quantile": float(self.quantile),
                "margin": bool(self.margin), "noise": dataclasses.asdict(self.noise)}

    def columns(self, points, normals, *, mu, num_edges, torque_test, contact, torsion) -> dict:
        """``{column: (N,) array}`` of the grasps ``points``, ``normals`` ``(N, n, d)``."""
        import jax

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            res = robust(self.obj, points, normals, mu=mu, noise=self.noise, key=jax.random.key(self.seed),
                         samples=self.samples, quantile=self.quantile, num_edges=num_edges,
                         torque_test=torque_test, contact=contact, torsion=torsion, margin=self.margin)
        return {self.COLUMNS[f]: v for f, v in res.columns().items()}

    def jaw_columns(self, chunk: Mapping, *, gripper, collision: bool, mu, num_edges, torque_test, contact,
                    torsion) -> dict:
        """``{column: (N,) array}`` of the parallel-jaw grasps of ``chunk`` (``center``, ``axis``,
        ``width``[, ``approach``]) by :func:`grasp_jax.grippers.robust_jaws` on ``obj``'s mesh."""
        import jax

        approaches = chunk.get("approach") if collision else None
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            res = robust_jaws(self.obj, chunk["center"], chunk["axis"], chunk["width"], approaches, mu=mu,
                              noise=self.noise, key=jax.random.key(self.seed), samples=self.samples,
                              gripper=gripper, collision=collision, quantile=self.quantile, num_edges=num_edges,
                              torque_test=torque_test, contact=contact, torsion=torsion, margin=self.margin)
        return {self.COLUMNS[f]: v for f, v in res.columns().items()}


def recast_jaws(robust: RobustLabels | None, extra_fields: tuple, metadata: Mapping):
    """``(gripper, collision)`` where the robust labels of a stream re-cast its parallel-jaw
    grasps (jaw poses in the chunks, noise that moves contacts), else ``None``."""
    if robust is None or not robust.noise.moves_contacts:
        return None
    if not {"center", "axis", "width", "jaw_status"} <= set(extra_fields):
        return None
    gripper = metadata.get("gripper")
    gripper = ParallelJaw.from_dict(gripper) if isinstance(gripper, Mapping) else None
    collision = bool(metadata.get("collision")) and gripper is not None and gripper.has_body \
        and "approach" in extra_fields
    return gripper, collision


def with_object(robust: RobustLabels | None, obj) -> RobustLabels | None:
    """``robust`` with its object set to ``obj`` where it has none."""
    if robust is None or robust.obj is not None or obj is None:
        return robust
    return dataclasses.replace(robust, obj=obj)


__all__ = ["RobustLabels", "recast_jaws", "with_object"]
