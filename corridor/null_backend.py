"""A tiny backend with no external library: point masses moving at constant velocity unless commanded.

Tests drive the engine with it (Scenic keeps a dummy simulator for the same reason).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Backend, RunContext
from corridor.snapshot import Kind, Role, WorldSnapshot


@dataclass(frozen=True)
class SetVelocity:
    """Command: set the ENU velocity [m/s] of the point mass ``vid``."""

    vid: str
    velocity: tuple[float, float, float]  # [m/s] ENU


class NullBackend(Backend):
    """Point masses at constant velocity, stepped every ``period`` [s]; ``SetVelocity`` changes one."""

    def __init__(self, name: str, ids: list[str], position: np.ndarray, velocity: np.ndarray,
                 period: float = 0.1, kind: Kind = Kind.CAR) -> None:
        super().__init__(name)
        self.period = period
        self.ids = np.array(ids, dtype=object)
        self.position = np.asarray(position, dtype=float).copy()
        self.velocity = np.asarray(velocity, dtype=float).copy()
        self.kind = kind
        self.steps = 0

    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        """Apply the ``SetVelocity`` commands for this backend's point masses."""
        index = {v: k for k, v in enumerate(self.ids)}
        for c in commands:
            if isinstance(c, SetVelocity) and c.vid in index:
                self.velocity[index[c.vid]] = c.velocity

    def tick(self, ctx: RunContext) -> None:
        """Move every point mass by velocity x period."""
        self.position += self.velocity * self.period
        self.steps += 1

    def snapshot_part(self) -> WorldSnapshot:
        """The point masses as snapshot rows (4.5 x 1.8 x 1.5 m boxes, heading along the velocity)."""
        n = len(self.ids)
        return WorldSnapshot(
            ids=self.ids, kind=np.full(n, self.kind, dtype=np.int8), role=np.full(n, Role.OTHER, dtype=np.int8),
            position=self.position.copy(), velocity=self.velocity.copy(),
            heading=np.arctan2(self.velocity[:, 1], self.velocity[:, 0]), size=np.tile([4.5, 1.8, 1.5], (n, 1)))


class NullVehicle(BaseModel):
    """One point mass of a ``point_mass`` backend: start position [m] and velocity [m/s], ENU."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    x_m: float = 0.0  # [m] ENU start position
    y_m: float = 0.0  # [m]
    z_m: float = 0.0  # [m]
    vx_mps: float = 0.0  # [m/s] ENU velocity
    vy_mps: float = 0.0  # [m/s]
    vz_mps: float = 0.0  # [m/s]


class NullFleet(NullBackend):
    """The null backend as a scenario component (registry name ``point_mass``).

    Point masses at constant velocity, declared in the YAML.  Scenarios whose outcome is known in
    closed form (the analytic checks of the rare-event estimators) run on it without any simulator
    library.
    """

    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        """The point masses by name, and the kind of entity they stand for."""

        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        vehicles: dict[str, NullVehicle] = Field(min_length=1)
        kind: Literal["car", "truck", "uav", "aircraft", "obstacle"] = "car"

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        ids = list(params.vehicles)
        pos = np.array([[v.x_m, v.y_m, v.z_m] for v in params.vehicles.values()])
        vel = np.array([[v.vx_mps, v.vy_mps, v.vz_mps] for v in params.vehicles.values()])
        super().__init__(name, ids, pos, vel, scenario.dt, Kind[params.kind.upper()])
