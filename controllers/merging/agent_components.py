"""``merge_agent``: one ramp vehicle of the merging scenario driven by a learning agent (``corridor/Merge-v0``).

The ego is the first vehicle of the ramp route that departs at or after ``ego_depart_s`` (so the
mainline is already loaded with the scenario's calibrated human drivers; the other vehicles stay
theirs).  From then on, every tick (0.1 s):

- the action held (``act``) sets a target: a discrete meta-action (highway-env's ``LANE_LEFT``,
  ``IDLE``, ``LANE_RIGHT``, ``FASTER``, ``SLOWER``) moves the target speed among
  ``target_speeds_mps`` or requests a lane change; a continuous action ``[a, lane]`` in [-1, 1]²
  gives the acceleration (mapped onto ``accel_range_mps2``) and a lane-change request (``lane`` > 0.5:
  left, < -0.5: right);
- the acceleration (highway-env's speed controller towards the target, or the continuous one) passes
  the merging scenario's **safety layer** (``safe_accel``: the Gipps/RSS bound towards the leader on
  the ego's lane, as for the V2X-coordinated vehicles) and is sent as a ``SetSpeed`` in speed mode
  ``command_speed_mode`` (SUMO's own check on the physical leader stays on);
- lane changes are the agent's alone (the ego's own lane-change model is off: lane-change mode 512)
  and are executed by SUMO only into a gap that respects the others' safe gaps — the gap acceptance
  is the agent's, the safety of the gap is SUMO's.

Reward per decision (highway-env's ``merge-v0`` terms): ``collision_reward`` on a collision,
``high_speed_reward`` x the speed mapped from ``reward_speed_range_mps`` onto [0, 1],
``lane_change_reward`` per lane change made, ``merged_reward`` once when the ego reaches a
mainline lane.  The episode is done when the ego is ``goal_past_merge_m`` past the acceleration
lane's end (or leaves the network).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.ego_actions import (
    LANE_LEFT,
    LANE_RIGHT,
    MetaTarget,
    apply_meta,
    continuous,
    nearest_speed_index,
    speed_control,
    speed_reward,
)
from corridor.controllers.merging.components import deliverable_safety
from corridor.controllers.merging.safety_layer import SafetyParams, lane_leaders, safe_accel
from corridor.engine import Controller, Metric, RunContext
from corridor.snapshot import Role
from corridor.traffic.networks.landmarks import OnrampLandmarks
from corridor.traffic.sumo.commands import ChangeLane, SetLaneChangeMode, SetSpeed
from corridor.traffic.sumo.road_spec import require_landmarks
from corridor.traffic.sumo.trips import road_frame

AGENT_LANE_CHANGE_MODE = 512  # no own lane changes; TraCI-requested ones respect the others' gaps


class MergeAgent(Controller):
    """The agent's ramp vehicle (see the module docstring)."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('ego_merged', '1', '1 if the agent\'s ramp vehicle reached a mainline lane.'),
        Metric('ego_safety_caps', '1', "Ticks on which the safety layer lowered the agent's acceleration."),
    )
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        action: Literal["discrete", "continuous"] = "discrete"
        ego_depart_s: float = Field(60.0, ge=0.0)  # [s] the ego: the first ramp vehicle departing from then on
        target_speeds_mps: tuple[float, ...] = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)  # [m/s] increasing
        accel_range_mps2: tuple[float, float] = (-5.0, 5.0)  # [m/s²] continuous action (highway-env's)
        lane_change_s: float = Field(1.0, gt=0.0)  # [s] how long SUMO tries a requested lane change
        safety: SafetyParams = Field(default_factory=SafetyParams)
        command_speed_mode: int = Field(27, ge=0, le=31)  # as the V2X merging controller's
        goal_past_merge_m: float = Field(100.0, ge=0.0)  # [m] past the acceleration lane's end: done
        collision_reward: float = -1.0
        high_speed_reward: float = 0.2
        reward_speed_range_mps: tuple[float, float] = (20.0, 30.0)  # [m/s]
        lane_change_reward: float = -0.05
        merged_reward: float = 1.0

    @classmethod
    def check_scenario(cls, params: Params, scenario: Any) -> None:
        """At load: the road's network must have an on-ramp."""
        require_landmarks(scenario, OnrampLandmarks, "merge_agent")

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.ego: str | None = None
        self._action: Any = 1  # IDLE until the first act()
        self._lane_request = 0  # -1 right, +1 left, 0 none: sent on the next tick
        self.target: MetaTarget | None = None
        self.merged = False
        self.caps = 0
        self._changes = 0  # lane changes made in the current decision period
        self._newly_merged = False
        self._speed, self._x, self._lane_name, self._gone = 0.0, -math.inf, "", False

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        lm = road_frame(ctx).tables.landmarks
        if not isinstance(lm, OnrampLandmarks):
            raise ValueError(f"{self.name}: merge_agent needs an on-ramp network (highway_onramp)")
        self.lm = lm
        self.reference_xy = (float(lm.merge_end_x), 0.0)  # [m] the ego row's x, y are measured from here
        self.safety = deliverable_safety(self.p.safety, ctx.scenario, self.p.command_speed_mode, self.period)

    @property
    def ego_id(self) -> str | None:
        return self.ego

    # ------------------------------------------------------------------ the environment's side
    def act(self, action: Any) -> None:
        """Hold ``action`` from now on (a lane change is requested once)."""
        if self.p.action == "discrete":
            a = int(action)
            assert self.target is not None
            self.target = apply_meta(self.target, a, n_lanes=1)  # the speed; lanes: requests below
            self._lane_request = 1 if a == LANE_LEFT else -1 if a == LANE_RIGHT else 0
        else:
            self._action = np.clip(np.asarray(action, dtype=float).reshape(-1), -1.0, 1.0)
            if self._action.shape != (2,):
                raise ValueError(f"continuous action: expected 2 values, got {np.shape(action)}")
            lane = float(self._action[1])
            self._lane_request = 1 if lane > 0.5 else -1 if lane < -0.5 else 0

    def outcome(self, collided: bool) -> tuple[float, bool, dict[str, Any]]:
        """The decision period's reward, whether the episode is done, and its terms."""
        p = self.p
        speed01 = speed_reward(self._speed, *p.reward_speed_range_mps)
        reward = (p.collision_reward * collided + p.high_speed_reward * speed01
                  + p.lane_change_reward * self._changes + p.merged_reward * self._newly_merged)
        info = {"ego_speed_mps": self._speed, "ego_x_m": self._x, "ego_lane": self._lane_name,
                "ego_merged": int(self.merged), "crashed": bool(collided)}
        self._changes, self._newly_merged = 0, False
        return float(reward), self._gone or self._x >= self.lm.merge_end_x + p.goal_past_merge_m, info

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        if self.ego is None:
            self._pick_ego(ctx)
            return
        rows = np.flatnonzero(np.asarray(ctx.snapshot.ids[r.sl]) == self.ego)
        self._gone = rows.size == 0
        if self._gone:
            return
        k = int(rows[0])
        s = ctx.snapshot
        row = r.offset + k
        self._speed, self._x = float(s.speed[row]), float(s.position[row, 0])
        lane = r.tables.lane_names[int(r.lane[k])]
        if lane.rsplit("_", 1)[0] == self._lane_name.rsplit("_", 1)[0] and lane != self._lane_name:
            self._changes += 1  # a lane change done (on the same edge), not merely requested
        self._lane_name = lane
        if not self.merged and self._on_mainline(self._lane_name):
            self.merged = self._newly_merged = True
        ctx.commands.extend(self._commands(ctx, r, k))

    def _pick_ego(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        if ctx.t < self.p.ego_depart_s or len(r) == 0:
            return
        tb = r.tables
        cand = np.flatnonzero((tb.role[r.uid] == Role.RAMP) & (tb.depart_s[r.uid] >= self.p.ego_depart_s))
        if cand.size == 0:
            return
        k = int(cand[np.argmin(r.uid[cand])])
        self.ego = str(ctx.snapshot.ids[r.offset + k])
        v = float(ctx.snapshot.speed[r.offset + k])
        lane = int(r.tables.lane_names[int(r.lane[k])].rsplit("_", 1)[1])
        self.target = MetaTarget(tuple(self.p.target_speeds_mps), nearest_speed_index(self.p.target_speeds_mps, v), lane)
        self._speed, self._x, self._lane_name, self._gone = v, float(ctx.snapshot.position[r.offset + k, 0]), "", False
        ctx.events.emit(ctx.t, self.name, "ego_agent", f"{self.ego} is the agent's ramp vehicle", vid=self.ego)
        ctx.commands.append(SetLaneChangeMode(self.ego, AGENT_LANE_CHANGE_MODE))

    def _on_mainline(self, lane: str) -> bool:
        lm = self.lm
        return lane != lm.accel_lane and (lane.startswith(lm.merge_edge) or lane.startswith(lm.downstream_edge))

    def _commands(self, ctx: RunContext, r: Any, k: int) -> list[Any]:
        p, v, out = self.p, self._speed, []
        if p.action == "discrete":
            assert self.target is not None
            a_cmd = speed_control(v, self.target.speed_mps)
        else:
            a_cmd = continuous(self._action, (p.accel_range_mps2[0], -1.0), (p.accel_range_mps2[1], 1.0))[0]
        a_cmd = float(np.clip(a_cmd, *p.accel_range_mps2))
        gap, v_lead = self._leader(ctx, r, k)
        a = safe_accel(gap, v, v_lead, a_cmd, self.safety)
        self.caps += a < a_cmd
        out.append(SetSpeed(self.ego, max(0.0, v + a * self.period), p.command_speed_mode))
        if self._lane_request and not self._lane_name.startswith(":"):
            index = int(self._lane_name.rsplit("_", 1)[1]) + self._lane_request
            if index >= 0:  # an index the edge lacks is ignored by SUMO
                out.append(ChangeLane(self.ego, index, p.lane_change_s))
            self._lane_request = 0
        return out

    def _leader(self, ctx: RunContext, r: Any, k: int) -> tuple[float, float]:
        """Bumper-to-bumper gap [m] and speed [m/s] of the ego's leader on its lane (inf: none)."""
        lead = int(lane_leaders(r.lane, r.lane_pos)[k])
        if lead < 0:
            return math.inf, 0.0
        s = ctx.snapshot
        gap = float(r.lane_pos[lead] - s.size[r.offset + lead, 0] - r.lane_pos[k])
        return gap, float(s.speed[r.offset + lead])

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"ego_merged": int(self.merged), "ego_safety_caps": self.caps}
