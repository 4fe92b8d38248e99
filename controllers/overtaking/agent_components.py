"""``overtaking_agent``: the overtaking scenario's ego bicycle driven by a learning agent (``corridor/Overtaking-v0``).

It takes the place of the STL overtaking MPC (``overtaking``): the same ego backend (a kinematic
bicycle integrated by corridor and placed into SUMO), the same slow lead, follower and random oncoming
traffic, the same ``overtaking_safety`` monitor and STL specs.  Every tick (0.1 s) it turns the action
held (``act``) into an ``EgoInput``:

- discrete meta-actions (highway-env's ``LANE_LEFT`` = into the oncoming lane, ``IDLE``,
  ``LANE_RIGHT`` = back into the own lane, ``FASTER``, ``SLOWER``) move a target lane and a target speed
  (``target_speeds_mps``), tracked by highway-env's speed and lateral controllers;
- a continuous action ``[a, steer]`` in [-1, 1]² is mapped onto the bicycle's acceleration and
  steering limits (highway-env's ``ContinuousAction``).

The acceleration then passes the **safety layer** (``safe_accel``, the Gipps/RSS bound of the merging
controllers) towards the nearest same-direction vehicle ahead that overlaps the ego laterally (the
lead while behind it).  Oncoming traffic is not bounded: avoiding it is the agent's task, and a
collision ends the episode.

Reward per decision: ``collision_reward`` on a collision (or leaving the road: more than
``off_road_m`` outside the two lanes), ``high_speed_reward`` x the speed mapped from
``reward_speed_range_mps`` onto [0, 1], ``own_lane_reward`` while in the own lane, ``pass_reward`` once
when the pass is completed (ahead of the lead by ``pass_margin_m`` and back within 0.5 m of the own
lane's centre, the scenario's ``completion`` spec), which ends the episode.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.ego_actions import (
    MetaTarget,
    apply_meta,
    continuous,
    nearest_speed_index,
    speed_control,
    speed_reward,
    steering_control,
)
from corridor.controllers.merging.safety_layer import SafetyParams, safe_accel
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.traffic.networks.landmarks import RuralLandmarks
from corridor.traffic.sumo.trips import road_frame
from corridor.vehicles.ground.ego_bicycle import EgoBicycle, EgoInput


class OvertakingAgent(Controller):
    """The agent's ego bicycle on the rural road (see the module docstring)."""

    needs: ClassVar[dict[str, Need]] = {"ego": Need(role="ego", name_at="p.ego")}
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('ego_passed', '1', '1 if the agent completed the pass.'),
        Metric('ego_safety_caps', '1', "Ticks on which the safety layer lowered the agent's acceleration."),
    )
    period_source: ClassVar[str | None] = "dt"
    ego: EgoBicycle

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        action: Literal["discrete", "continuous"] = "discrete"
        ego: str = "ego"  # the EgoBicycle backend component
        lead: str = "lead"  # the vehicle to pass (a companion of the ego)
        target_speeds_mps: tuple[float, ...] = (10.0, 15.0, 20.0, 25.0, 30.0)  # [m/s] increasing
        safety: SafetyParams = Field(default_factory=SafetyParams)
        pass_margin_m: float = Field(5.0, ge=0.0)  # [m] ahead of the lead's front bumper: passed
        off_road_m: float = Field(1.0, ge=0.0)  # [m] beyond the outer lane edges: off the road
        collision_reward: float = -1.0
        high_speed_reward: float = 0.4
        reward_speed_range_mps: tuple[float, float] = (15.0, 25.0)  # [m/s]
        own_lane_reward: float = 0.1
        pass_reward: float = 1.0

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.target: MetaTarget | None = None
        self._action: Any = None
        self.passed = self._newly_passed = self.off_road = False
        self.caps = 0
        self._state = np.zeros(4)

    def setup(self, ctx: RunContext) -> None:
        marks = road_frame(ctx).tables.landmarks
        if not isinstance(marks, RuralLandmarks):
            raise ValueError(f"{self.name}: overtaking_agent needs the rural two-lane road, not {marks.kind!r}")
        self.lane_y = float(marks.east_lane_y)  # [m] ENU y of the own lane's centre
        self.width = float(marks.opposite_lane_offset_m)  # [m] to the oncoming lane's centre (+y: left)
        self.reference_xy = (0.0, self.lane_y)  # [m] the ego row's y: offset from the own lane's centre
        self.bike = self.ego.p.bicycle
        super().setup(ctx)

    @property
    def ego_id(self) -> str | None:
        return self.ego.vid if self.ego.active else None

    def vid_of(self, slot: str) -> str | None:
        return self.ego_id  # one agent

    # ------------------------------------------------------------------ the environment's side
    def act(self, action: Any, slot: str = "ego") -> None:
        """Hold ``action`` from now on."""
        if self.p.action == "discrete":
            if self.target is None:
                v = float(self.ego.state[3])
                self.target = MetaTarget(tuple(self.p.target_speeds_mps), nearest_speed_index(self.p.target_speeds_mps, v), 0)
            self.target = apply_meta(self.target, int(action), 2)
        else:
            b = self.bike
            self._action = continuous(action, (b.accel_min_mps2, -b.steer_max_rad), (b.accel_max_mps2, b.steer_max_rad))

    def outcome(self, collided: bool, slot: str = "ego") -> tuple[float, bool, dict[str, Any]]:
        """The decision period's reward, whether the episode is done, and its terms."""
        p = self.p
        _, y, _, v = self._state
        lateral = float(y) - self.lane_y
        own = abs(lateral) < 0.5 * abs(self.width)
        crashed = collided or self.off_road
        reward = (p.collision_reward * crashed + p.high_speed_reward * speed_reward(float(v), *p.reward_speed_range_mps)
                  + p.own_lane_reward * own + p.pass_reward * self._newly_passed)
        info = {"ego_speed_mps": float(v), "ego_lateral_m": lateral, "ego_passed": int(self.passed),
                "crashed": bool(crashed), "off_road": bool(self.off_road)}
        self._newly_passed = False
        return float(reward), self.passed or self.off_road or not self.ego.active, info

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        if not self.ego.active:
            return
        x, y, yaw, v = (float(z) for z in self.ego.state)
        self._state = np.array([x, y, yaw, v])
        lateral = y - self.lane_y
        lo, hi = -0.5 * abs(self.width) - self.p.off_road_m, 1.5 * abs(self.width) + self.p.off_road_m
        self.off_road = self.off_road or not lo <= lateral * np.sign(self.width) <= hi
        self._check_pass(ctx, x, lateral)
        if self.p.action == "discrete":
            if self.target is None:
                self.target = MetaTarget(tuple(self.p.target_speeds_mps), nearest_speed_index(self.p.target_speeds_mps, v), 0)
            a_cmd = speed_control(v, self.target.speed_mps)
            steer = steering_control(lateral - self.target.lane * self.width, yaw, v, self.bike.wheelbase_m)
        else:
            a_cmd, steer = self._action if self._action is not None else (0.0, 0.0)
        a_cmd = float(np.clip(a_cmd, self.bike.accel_min_mps2, self.bike.accel_max_mps2))
        gap, v_lead = self._leader(ctx, x, y)
        a = safe_accel(gap, v, v_lead, a_cmd, self.p.safety)
        self.caps += a < a_cmd
        ctx.commands.append(EgoInput(self.ego.vid, a, steer))

    def _front_x(self, x: float) -> float:
        return x + 0.5 * self.bike.wheelbase_m + 0.5 * self.bike.length_m  # rear axle -> front bumper

    def _check_pass(self, ctx: RunContext, x: float, lateral: float) -> None:
        s = ctx.snapshot
        k = s.index().get(self.p.lead)
        if self.passed or k is None:
            return
        lead_front = float(s.position[k, 0] + 0.5 * s.size[k, 0])
        rear = x - (0.5 * self.bike.length_m - 0.5 * self.bike.wheelbase_m)  # the ego's rear bumper
        if rear > lead_front + self.p.pass_margin_m and abs(lateral) < 0.5:
            self.passed = self._newly_passed = True
            ctx.events.emit(ctx.t, self.name, "ego_passed", f"{self.ego.vid} passed {self.p.lead}")

    def _leader(self, ctx: RunContext, x: float, y: float) -> tuple[float, float]:
        """Gap [m] and speed [m/s] to the nearest same-direction vehicle ahead overlapping the ego."""
        s = ctx.snapshot
        front = self._front_x(x)
        pos, vx, length = np.asarray(s.position), np.asarray(s.velocity)[:, 0], np.asarray(s.size)[:, 0]
        rear = pos[:, 0] - 0.5 * length
        ahead = (s.ids != self.ego.vid) & (vx > 0.0) & (rear > front - 0.5 * self.bike.length_m) \
            & (np.abs(pos[:, 1] - y) < 0.5 * (np.asarray(s.size)[:, 1] + self.bike.width_m))
        if not ahead.any():
            return math.inf, 0.0
        k = int(np.flatnonzero(ahead)[np.argmin(rear[ahead])])
        return float(rear[k] - front), float(vx[k])

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"ego_passed": int(self.passed), "ego_safety_caps": self.caps}
