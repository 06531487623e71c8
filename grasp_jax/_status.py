"""The base of every status code: an ``int8`` per grasp or problem whose member has a message."""

from __future__ import annotations

import enum

import numpy as np


class StatusEnum(enum.IntEnum):
    """An integer status whose members are declared ``NAME = code, "message"`` (as lineax's
    ``RESULTS``): ``Status.OPTIMAL == 0`` and ``Status.OPTIMAL.message == "optimal"``."""

    def __new__(cls, value: int, message: str = ""):
        member = int.__new__(cls, value)
        member._value_ = value
        member._message = message
        return member

    @property
    def message(self) -> str:
        """One sentence saying what the status means."""
        return self._message

    @classmethod
    def counts(cls, codes) -> dict[StatusEnum, int]:
        """``{member: count}`` of the members present in ``codes`` (any integer array)."""
        values, counts = np.unique(np.asarray(codes).ravel(), return_counts=True)
        return {cls(int(v)): int(c) for v, c in zip(values, counts)}
