"""Kinematic bicycle model, written once and shared by the simulator, the MPC and the predictor.

State ``x = (px, py, psi, v)``: rear-axle position [m], heading [rad] (0 along +x, counter-clockwise
positive) and speed [m/s].  Input ``u = (a, delta)``: longitudinal acceleration [m/s^2] and front
steering angle [rad].  With the reference point on the rear axle the model is

    px' = v cos(psi),   py' = v sin(psi),   psi' = v tan(delta) / L,   v' = a

so a constant steering angle gives a circle of radius ``L / tan(delta)`` exactly (checked in the tests).

``f`` accepts numpy arrays *or* CasADi symbols (SX/MX/DM), so the MPC transcribes the very same
function; ``rk4_step`` is the shared discretisation (the simulator harness, the MPC's multiple-shooting
constraints and the replay of plans all call it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

N_STATE = 4  # (px, py, psi, v)
N_INPUT = 2  # (accel, steer)


class BicycleParams(BaseModel):
    """Geometry and actuator limits of the ego vehicle."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    wheelbase_m: float = Field(2.7, gt=0.0)  # [m]
    length_m: float = Field(4.5, gt=0.0)  # [m] body length (collision box)
    width_m: float = Field(1.8, gt=0.0)  # [m] body width (collision box)
    accel_min_mps2: float = Field(-6.0, lt=0.0)  # [m/s^2] hardest braking
    accel_max_mps2: float = Field(3.0, gt=0.0)  # [m/s^2]
    steer_max_rad: float = Field(0.35, gt=0.0, lt=1.5)  # [rad]
    speed_max_mps: float = Field(30.0, gt=0.0)  # [m/s] model validity, not the speed limit


def _is_symbolic(*xs: Any) -> bool:
    return any(isinstance(z, ca.SX | ca.MX | ca.DM) for z in xs)


def f(x: Any, u: Any, params: BicycleParams) -> Any:
    """State derivative of the kinematic bicycle; numpy in -> numpy out, CasADi in -> CasADi out."""
    if _is_symbolic(x, u):
        psi, v, a, delta = x[2], x[3], u[0], u[1]
        return ca.vertcat(v * ca.cos(psi), v * ca.sin(psi), v * ca.tan(delta) / params.wheelbase_m, a)
    x_arr = np.asarray(x, dtype=float)
    u_arr = np.asarray(u, dtype=float)
    psi, v, a, delta = x_arr[2], x_arr[3], u_arr[0], u_arr[1]
    return np.array([v * np.cos(psi), v * np.sin(psi), v * np.tan(delta) / params.wheelbase_m, a])


Dynamics = Callable[[Any, Any, BicycleParams], Any]


def rk4_step(x: Any, u: Any, dt_s: float, params: BicycleParams, dyn: Dynamics = f) -> Any:
    """One classic Runge-Kutta-4 step of ``dyn`` with the input held constant over ``dt_s``."""
    k1 = dyn(x, u, params)
    k2 = dyn(x + 0.5 * dt_s * k1, u, params)
    k3 = dyn(x + 0.5 * dt_s * k2, u, params)
    k4 = dyn(x + dt_s * k3, u, params)
    return x + dt_s / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def integrate(x0: np.ndarray, u: np.ndarray, dt_s: float, params: BicycleParams,
              substeps: int = 1) -> np.ndarray:
    """Integrate the input sequence ``u`` [K, 2] (zero-order hold, ``dt_s`` each) from ``x0``.

    Returns the state trajectory [K + 1, 4] including ``x0``; ``substeps`` RK4 steps per input.
    """
    xs = np.empty((len(u) + 1, N_STATE))
    xs[0] = np.asarray(x0, dtype=float)
    h = dt_s / substeps
    for k, uk in enumerate(np.asarray(u, dtype=float)):
        xk = xs[k]
        for _ in range(substeps):
            xk = rk4_step(xk, uk, h, params)
        xs[k + 1] = xk
    return xs


def clip_input(u: np.ndarray, params: BicycleParams) -> np.ndarray:
    """Saturate ``(accel, steer)`` to the actuator limits."""
    return np.array([
        float(np.clip(u[0], params.accel_min_mps2, params.accel_max_mps2)),
        float(np.clip(u[1], -params.steer_max_rad, params.steer_max_rad)),
    ])
