"""The parallel-jaw gripper model and the per-grasp status of its contacts."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .._status import StatusEnum


class JawStatus(StatusEnum):
    """Why a parallel-jaw grasp has (or has not) two contacts (``int8`` per grasp).

    Rows that are not ``OK`` are never force-closure: :func:`grasp_jax.grippers.score_grasps` and
    ``grasp-jax sample --gripper parallel-jaw`` give them verdict ``False``, Q 0 and critical
    friction ``inf``.
    """

    #: Two contacts: each jaw met the surface between the open jaws, from outside the object.
    OK = 0, "two contacts"
    #: The closing line meets the mesh fewer than twice, or not between the open jaws.
    MISSED = 1, "the closing line meets the object fewer than twice between the open jaws"
    #: The object extends beyond the opening: a jaw starts inside the material.
    TOO_WIDE = 2, "the object extends beyond the opening (a jaw starts inside it)"
    #: The gripper body (finger boxes or palm) intersects the object (``collision=True`` only).
    COLLISION = 3, "the gripper body intersects the object"
    #: The contacts are closer than the gripper's ``min_width``: the jaws stop before touching.
    TOO_NARROW = 4, "the contacts are closer than the gripper's smallest opening"


def _box(name: str, value) -> tuple[float, float, float] | None:
    if value is None:
        return None
    try:
        size = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be three lengths > 0; got {value!r}") from None
    if len(size) != 3 or not all(math.isfinite(v) and v > 0 for v in size):
        raise ValueError(f"{name} must be three finite lengths > 0; got {value!r}")
    return size


@dataclass(frozen=True)
class ParallelJaw:
    """A parallel-jaw gripper: two flat fingers closing along one axis, and a palm behind them.

    Every length is in the units of the object the gripper grasps (metres for YCB meshes).

    The gripper's frame at a grasp is ``(axis, binormal, approach)`` with
    ``binormal = approach x axis``: the jaws close along ``axis`` towards the grasp centre, the
    hand moves in along ``approach``. The collision body, used only by the optional collision
    check, is three boxes in that frame: two fingers whose inner faces are the open jaws (at
    ``-/+ width / 2`` along ``axis``), centred on the closing line across it, their tips
    ``tip_depth`` beyond the closing line along ``approach``, and a palm behind them (towards
    ``-approach``), centred on the axis.

    Attributes:
        max_width: largest opening, > 0.
        min_width: smallest opening, ``0 <= min_width < max_width``; contacts closer than this
            get :attr:`JawStatus.TOO_NARROW`.
        finger_size: ``(thickness, breadth, length)`` of each finger box: along ``axis``, along
            ``binormal`` and along ``approach``; ``None``: no collision body.
        palm_size: ``(span, breadth, depth)`` of the palm box along ``axis``, ``binormal`` and
            ``approach``; ``None``: no palm.
        tip_depth: how far the finger tips reach beyond the closing line, ``0 <= tip_depth <=
            finger length`` (default a quarter of the finger's length).

    Raises:
        ValueError: a width or size that is not a finite positive length, ``min_width >=
            max_width``, or a palm without fingers.
    """

    max_width: float
    min_width: float = 0.0
    finger_size: tuple[float, float, float] | None = None
    palm_size: tuple[float, float, float] | None = None
    tip_depth: float | None = None

    def __post_init__(self):
        for name in ("max_width", "min_width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number; got {value!r}")
        if not self.max_width > 0:
            raise ValueError(f"max_width must be > 0; got {self.max_width!r}")
        if not 0 <= self.min_width < self.max_width:
            raise ValueError(f"min_width must be in [0, max_width = {self.max_width}); got {self.min_width!r}")
        object.__setattr__(self, "max_width", float(self.max_width))
        object.__setattr__(self, "min_width", float(self.min_width))
        object.__setattr__(self, "finger_size", _box("finger_size", self.finger_size))
        object.__setattr__(self, "palm_size", _box("palm_size", self.palm_size))
        if self.palm_size is not None and self.finger_size is None:
            raise ValueError("a palm_size needs a finger_size: the palm sits behind the fingers")
        if self.finger_size is None:
            if self.tip_depth is not None:
                raise ValueError("a tip_depth needs a finger_size")
            return
        length = self.finger_size[2]
        tip = 0.25 * length if self.tip_depth is None else self.tip_depth
        if isinstance(tip, bool) or not isinstance(tip, (int, float)) or not 0 <= tip <= length:
            raise ValueError(f"tip_depth must be a length in [0, finger length {length}]; got {tip!r}")
        object.__setattr__(self, "tip_depth", float(tip))

    @classmethod
    def scaled(cls, max_width: float, min_width: float = 0.0) -> ParallelJaw:
        """A gripper with a collision body in proportion to its opening: fingers
        ``max_width / 8`` thick, ``max_width / 4`` broad and ``0.6 max_width`` long (tips a
        quarter of that beyond the closing line), a palm
        spanning the open jaws and both fingers, ``max_width / 4`` broad and deep (what
        ``grasp-jax sample --collision`` uses unless sizes are given)."""
        w = float(max_width)
        return cls(w, min_width, finger_size=(w / 8, w / 4, 0.6 * w), palm_size=(1.25 * w, w / 4, w / 4))

    @property
    def has_body(self) -> bool:
        """Whether the gripper has a collision body (a ``finger_size``)."""
        return self.finger_size is not None

    def to_dict(self) -> dict:
        """The gripper as JSON-ready metadata (``{"name": "parallel-jaw", ...}``)."""
        return {"name": "parallel-jaw", "max_width": self.max_width, "min_width": self.min_width,
                "finger_size": None if self.finger_size is None else list(self.finger_size),
                "palm_size": None if self.palm_size is None else list(self.palm_size),
                "tip_depth": self.tip_depth}

    @classmethod
    def from_dict(cls, data) -> ParallelJaw:
        """The inverse of :meth:`to_dict`."""
        return cls(float(data["max_width"]), float(data.get("min_width", 0.0)),
                   finger_size=data.get("finger_size"), palm_size=data.get("palm_size"),
                   tip_depth=data.get("tip_depth"))
