"""Parallel-jaw grippers: jaw poses, their contacts on a mesh, antipodal sampling, scoring.

A parallel-jaw grasp is a centre, a closing axis, an approach direction and an opening width
(:class:`ParallelJaw` says what the gripper can do). :func:`jaw_contacts` casts the closing line
onto the mesh (trimesh's ray queries) and returns the two contacts, their outward normals and a
:class:`JawStatus` per grasp; :func:`antipodal_grasps` samples poses in the manner of Dex-Net's
antipodal sampler; :func:`score_grasps` scores the contacts with :func:`grasp_jax.evaluate` and
:func:`grasp_jax.critical_friction` as two soft contacts; :func:`robust_jaws` labels grasps under
noise (:class:`grasp_jax.Noise`), casting each perturbed closing line again. An optional check of
the gripper's body (two finger boxes and a palm) against the object uses trimesh's collision
manager, which needs python-fcl (``pip install 'grasp_jax[grippers]'``). Lengths are in the object's units.

The guide: ``docs/guides/grippers.md``. Nothing here imports JAX but :func:`score_grasps` and
:func:`robust_jaws`.
"""

from __future__ import annotations

from ._antipodal import POSE_FIELDS as POSE_FIELDS
from ._antipodal import AntipodalGrasps as AntipodalGrasps
from ._antipodal import antipodal_grasps as antipodal_grasps
from ._antipodal import iter_antipodal_grasps as iter_antipodal_grasps
from ._contacts import JawContacts as JawContacts
from ._contacts import gripper_boxes as gripper_boxes
from ._contacts import jaw_contacts as jaw_contacts
from ._gripper import JawStatus as JawStatus
from ._gripper import ParallelJaw as ParallelJaw
from ._robust import robust_jaws as robust_jaws
from ._score import JawScores as JawScores
from ._score import score_grasps as score_grasps

__all__ = [
    "ParallelJaw",
    "JawStatus",
    "jaw_contacts",
    "JawContacts",
    "antipodal_grasps",
    "iter_antipodal_grasps",
    "AntipodalGrasps",
    "POSE_FIELDS",
    "score_grasps",
    "JawScores",
    "robust_jaws",
    "gripper_boxes",
]
