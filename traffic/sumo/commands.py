"""External-control commands for road vehicles (applied by the SUMO backend in the *act* phase).

Controllers return these from ``step``; they never call libsumo themselves.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SetSpeed:
    """Drive at ``speed_mps`` from now on (SUMO's safe-speed checks per ``speed_mode``)."""

    vid: str
    speed_mps: float
    speed_mode: int | None = None  # SUMO bitset; 32 = no checks, 31 = default (all checks)


@dataclass(frozen=True)
class SetAccel:
    """Accelerate at ``accel_mps2`` over the next ``duration_s`` seconds."""

    vid: str
    accel_mps2: float
    duration_s: float = 0.1
    speed_mode: int | None = None


@dataclass(frozen=True)
class ChangeLane:
    vid: str
    lane_index: int
    duration_s: float = 3.0


@dataclass(frozen=True)
class SetLaneChangeMode:
    """SUMO lane-change mode bitset from now on (e.g. 512: no own lane changes, TraCI changes that
    respect others' gaps); ``Release`` restores the vehicle's original mode."""

    vid: str
    mode: int


@dataclass(frozen=True)
class MoveToXY:
    """Place the vehicle at (x, y) [m] with heading ``yaw_rad`` (ENU, CCW from east)."""

    vid: str
    x: float
    y: float
    yaw_rad: float
    speed_mps: float
    edge: str = ""
    lane: int = -1
    keep_route: int = 2  # 2: anywhere, mapped to the nearest lane


@dataclass(frozen=True)
class Release:
    """Hand the vehicle back to SUMO's own driver model."""

    vid: str
