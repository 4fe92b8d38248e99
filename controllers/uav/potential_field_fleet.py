"""The potential field of ``potential_field.py`` for a whole fleet at once: every ego's command from
its (ego, other) pairs in one vectorised pass.

:func:`fleet_commands` takes the egos' own states and goals, and a list of pairs (ego row, other
row) with the others as the ego knows them (position, velocity, uncertainty radius, piloted flag),
and returns what :class:`~corridor.controllers.uav.potential_field.PotentialFieldAvoidance.step`
returns for each ego: the same arithmetic (repulsion with the closing-speed shrinkage, the C1 soft
floor, the bounded support, the vortex for agents ahead, the conic goal well, the saturation), summed
per ego with ``np.bincount``. ``tests/controllers/test_ctrl_potential_field_fleet.py`` checks it
against the per-UAV method. This module imports no engine code.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from corridor.controllers.uav.potential_field import PotentialFieldParams, pair_repulsion


class FleetCommands(NamedTuple):
    v_cmd: np.ndarray  # (N, 3) [m/s] saturated velocity commands
    avoiding: np.ndarray  # (N,) bool: the repulsion changed the command (> 10 % of the speed limit)
    repulsion_mps: np.ndarray  # (N,) [m/s]


def _sum_rows(rows: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Per-ego sums (n, 3) of pair values (K, 3)."""
    return np.column_stack([np.bincount(rows, values[:, d], minlength=n) for d in range(3)])


def goal_flow(x: np.ndarray, goal: np.ndarray, p: PotentialFieldParams) -> np.ndarray:
    """-grad J_goal (N, 3) [m/s]: quadratic within d_q, conic beyond."""
    e = x - goal
    r = np.linalg.norm(e, axis=1)
    k, dq = p.goal_gain_per_s, p.goal_quadratic_radius_m
    scale = np.where(r <= dq, 2.0 * k, 2.0 * k * dq / np.maximum(r, 1e-12))
    return -scale[:, None] * e


def fleet_commands(x: np.ndarray, v: np.ndarray, goal: np.ndarray, ego: np.ndarray, o_pos: np.ndarray,
                   o_vel: np.ndarray, sigma: np.ndarray, piloted: np.ndarray, p: PotentialFieldParams
                   ) -> FleetCommands:
    """Commands of N egos (``x``, ``v``, ``goal`` (N, 3)) given K pairs: ``ego`` (K,) rows into the
    egos and the other member's ``o_pos``, ``o_vel`` (K, 3), ``sigma`` [m], ``piloted`` (K,)."""
    n = len(x)
    g = goal_flow(x, goal, p)
    raw = g.copy()
    if len(ego):
        rep = pair_repulsion(x[ego], v[ego], o_pos, o_vel, sigma, piloted, p)
        raw += _sum_rows(ego, rep, n)
        ahead = np.einsum("kd,kd->k", o_pos - x[ego], goal[ego] - x[ego]) > 0.0
        r = _sum_rows(ego[ahead], rep[ahead], n)
        raw += p.vortex_gain * np.column_stack([-r[:, 1], r[:, 0], np.zeros(n)])
    repulsion = np.linalg.norm(raw - g, axis=1)
    h = np.hypot(raw[:, 0], raw[:, 1])
    cmd = raw.copy()
    cmd[:, :2] *= np.minimum(1.0, p.max_speed_h_mps / np.maximum(h, 1e-12))[:, None]
    cmd[:, 2] = np.clip(raw[:, 2], -p.max_climb_mps, p.max_climb_mps)
    return FleetCommands(cmd, repulsion > 0.1 * p.max_speed_h_mps, repulsion)
