"""World snapshot: one struct-of-arrays view of every entity, in the scenario's local ENU frame.

Backends fill it each tick (``WorldSnapshot.from_parts`` concatenates their blocks); cross-domain
logic (collision checks between anything, a UAV counting cars below it) reads only this, vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class Kind(IntEnum):
    """Entity kinds; stored as int8 in ``WorldSnapshot.kind``."""

    CAR = 0
    TRUCK = 1
    UAV = 2
    AIRCRAFT = 3
    OBSTACLE = 4


class Role(IntEnum):
    """What an entity is doing in the scenario (colouring, metrics grouping)."""

    MAINLINE = 0
    RAMP = 1
    CONTROLLED = 2
    OTHER = 3


@dataclass
class WorldSnapshot:
    """Struct-of-arrays state of all entities at time ``t`` [s].

    position/velocity are ENU metres and m/s; heading is the yaw angle [rad] measured
    counter-clockwise from east (ENU convention); size is (length, width, height) [m].
    """

    t: float = 0.0
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    role: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    heading: np.ndarray = field(default_factory=lambda: np.zeros(0))
    size: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    @property
    def speed(self) -> np.ndarray:
        """Horizontal speed [m/s]."""
        return np.hypot(self.velocity[:, 0], self.velocity[:, 1])

    def index(self) -> dict[str, int]:
        """Map id -> row (built on demand; cheap for the sizes of a tick)."""
        return {str(i): k for k, i in enumerate(self.ids)}

    def select(self, mask: np.ndarray) -> WorldSnapshot:
        return WorldSnapshot(
            self.t, self.ids[mask], self.kind[mask], self.role[mask], self.position[mask],
            self.velocity[mask], self.heading[mask], self.size[mask],
        )

    @staticmethod
    def from_parts(t: float, parts: list[WorldSnapshot]) -> WorldSnapshot:
        parts = [p for p in parts if len(p)]
        if not parts:
            return WorldSnapshot(t=t)
        if len(parts) == 1:
            p = parts[0]
            p.t = t
            return p
        return WorldSnapshot(
            t=t,
            ids=np.concatenate([p.ids for p in parts]),
            kind=np.concatenate([p.kind for p in parts]),
            role=np.concatenate([p.role for p in parts]),
            position=np.concatenate([p.position for p in parts]),
            velocity=np.concatenate([p.velocity for p in parts]),
            heading=np.concatenate([p.heading for p in parts]),
            size=np.concatenate([p.size for p in parts]),
        )
