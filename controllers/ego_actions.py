"""An ego vehicle driven by a learning agent: highway-env's action conventions as plain functions.

highway-env (Leurent 2018) gives an agent either *discrete meta-actions* — ``LANE_LEFT``, ``IDLE``,
``LANE_RIGHT``, ``FASTER``, ``SLOWER`` (``DiscreteMetaAction``), which move a target lane and a
target speed (one of ``target_speeds``) that low-level controllers then track — or a *continuous*
action in [-1, 1]² mapped linearly onto an acceleration and a steering range (``ContinuousAction``).
The low-level controllers here are highway-env's ``ControlledVehicle`` ones: a proportional speed
controller (time constant 0.6 s) and a cascaded lateral-position -> heading -> yaw-rate controller
(0.6 s and 0.2 s), the yaw rate turned into a steering angle with the kinematic bicycle.

Pure functions on numbers (no engine code): the scenario components (``merge_agent``,
``overtaking_agent``) hold the targets, apply the result through the scenario's safety layer and put
the commands on the bus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

META_ACTIONS: tuple[str, ...] = ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")  # highway-env's order
LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER = range(5)
TAU_ACC_S = 0.6  # [s] highway-env ControlledVehicle.TAU_ACC
TAU_LATERAL_S = 0.6  # [s] TAU_LATERAL
TAU_HEADING_S = 0.2  # [s] TAU_HEADING
MAX_HEADING_REF_RAD = math.pi / 4  # [rad] highway-env clips the heading command to this


@dataclass
class MetaTarget:
    """What a meta-action moves: the target speed's index in ``speeds`` and the target lane (0 = the
    rightmost lane the ego may use, counting leftwards)."""

    speeds: tuple[float, ...]  # [m/s] the target speeds, increasing
    speed_index: int
    lane: int

    @property
    def speed_mps(self) -> float:
        return self.speeds[self.speed_index]


def apply_meta(target: MetaTarget, action: int, n_lanes: int) -> MetaTarget:
    """The target after one meta-action (lanes clamped to ``0 .. n_lanes - 1``, speeds to the list)."""
    if not 0 <= action < len(META_ACTIONS):
        raise ValueError(f"meta-action {action}: must be 0..{len(META_ACTIONS) - 1} ({', '.join(META_ACTIONS)})")
    lane, k = target.lane, target.speed_index
    if action == LANE_LEFT:
        lane = min(lane + 1, n_lanes - 1)
    elif action == LANE_RIGHT:
        lane = max(lane - 1, 0)
    elif action == FASTER:
        k = min(k + 1, len(target.speeds) - 1)
    elif action == SLOWER:
        k = max(k - 1, 0)
    return MetaTarget(target.speeds, k, lane)


def nearest_speed_index(speeds: tuple[float, ...], v_mps: float) -> int:
    """The index of the target speed closest to ``v_mps`` (the ego's initial target)."""
    return int(np.argmin(np.abs(np.asarray(speeds) - v_mps)))


def speed_control(v_mps: float, v_target_mps: float) -> float:
    """Acceleration [m/s²] towards the target speed (highway-env: ``KP_A (v_target - v)``)."""
    return (v_target_mps - v_mps) / TAU_ACC_S


def steering_control(lateral_m: float, yaw_rad: float, v_mps: float, wheelbase_m: float,
                     lane_yaw_rad: float = 0.0) -> float:
    """Front steering angle [rad] that brings the ego onto a lane centre ``lateral_m`` to its right
    (positive: the ego is left of the centre): lateral speed -> heading -> yaw rate -> steering."""
    v = max(v_mps, 1.0)  # [m/s] highway-env's not_zero, with a floor that keeps the gains finite
    lateral_speed_cmd = -lateral_m / TAU_LATERAL_S
    heading_cmd = math.asin(float(np.clip(lateral_speed_cmd / v, -1.0, 1.0)))
    heading_ref = lane_yaw_rad + float(np.clip(heading_cmd, -MAX_HEADING_REF_RAD, MAX_HEADING_REF_RAD))
    yaw_err = (heading_ref - yaw_rad + math.pi) % (2.0 * math.pi) - math.pi
    yaw_rate_cmd = yaw_err / TAU_HEADING_S
    return math.atan(wheelbase_m * yaw_rate_cmd / v)  # rear-axle bicycle: yaw rate = v tan(delta) / L


def continuous(action: np.ndarray | list[float], low: tuple[float, float], high: tuple[float, float]) -> tuple[float, float]:
    """A continuous action in [-1, 1]² mapped linearly onto ``[low, high]`` per component."""
    a = np.clip(np.asarray(action, dtype=float).reshape(-1), -1.0, 1.0)
    if a.shape != (2,):
        raise ValueError(f"continuous action: expected 2 values in [-1, 1], got shape {np.shape(action)}")
    return tuple(float(lo + (x + 1.0) * 0.5 * (hi - lo)) for x, lo, hi in zip(a, low, high))  # type: ignore[return-value]


def speed_reward(v_mps: float, v_lo_mps: float, v_hi_mps: float) -> float:
    """highway-env's ``high_speed_reward`` term: the speed mapped from ``[v_lo, v_hi]`` onto [0, 1]."""
    return float(np.clip((v_mps - v_lo_mps) / (v_hi_mps - v_lo_mps), 0.0, 1.0))
