"""``merge_agent``: one ramp vehicle of the merging scenario driven by a learning agent (``corridor/Merge-v0``).

The ego is the first vehicle of the ramp route that departs at or after ``ego_depart_s`` (so the
mainline is already loaded with the scenario's calibrated human drivers; the other vehicles stay
theirs).  With ``agents: N`` > 1 (the PettingZoo environment ``corridor.ego_env.EgoParallelEnv``) the
agents are the first N *connected* vehicles, ramp or mainline, departed from then on, that come
within ``agent_zone_m`` of the nose: agent slot ``cv_k`` drives the k-th of them.  From then on, every tick (0.1 s), for each driven vehicle:

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
``lane_change_reward`` per lane change made, ``merged_reward`` once when a ramp vehicle reaches a
mainline lane.  The episode is done when the ego is ``goal_past_merge_m`` past the acceleration
lane's end (or leaves the network).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
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


@dataclass
class Driven:
    """One vehicle the agent drives: what its actions set and what its last tick saw."""

    vid: str
    target: MetaTarget
    action: np.ndarray = field(default_factory=lambda: np.zeros(2))  # continuous [a, lane] in [-1, 1]
    lane_request: int = 0  # -1 right, +1 left, 0 none: sent on the next tick
    speed: float = 0.0  # [m/s]
    x: float = -math.inf  # [m] ENU
    lane: str = ""
    merged: bool = False
    newly_merged: bool = False
    changes: int = 0  # lane changes made in the current decision period
    gone: bool = False
    ramp: bool = True  # a ramp vehicle (the merged reward is for these)


class MergeAgent(Controller):
    """The agent's ramp vehicle, or its N connected vehicles (see the module docstring)."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('ego_merged', '1', "1 if the agent's ramp vehicle reached a mainline lane (agents > 1: how many did)."),
        Metric('ego_safety_caps', '1', "Ticks on which the safety layer lowered the agent's acceleration."),
    )
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        action: Literal["discrete", "continuous"] = "discrete"
        ego_depart_s: float = Field(60.0, ge=0.0)  # [s] the ego: the first ramp vehicle departing from then on
        agents: int = Field(1, ge=1)  # > 1: the first N connected vehicles departed from ego_depart_s on
        agent_zone_m: float = Field(400.0, gt=0.0)  # [m] (agents > 1) ... once this close to the nose
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
        self.slots = ["ego"] if params.agents == 1 else [f"cv_{k}" for k in range(params.agents)]
        self.driven: dict[str, Driven] = {}  # slot -> its vehicle, once it departed
        self.caps = 0

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        lm = road_frame(ctx).tables.landmarks
        if not isinstance(lm, OnrampLandmarks):
            raise ValueError(f"{self.name}: merge_agent needs an on-ramp network (highway_onramp)")
        self.lm = lm
        self.reference_xy = (float(lm.merge_end_x), 0.0)  # [m] the ego row's x, y are measured from here
        self.safety = deliverable_safety(self.p.safety, ctx.scenario, self.p.command_speed_mode, self.period)

    # ------------------------------------------------------------------ the environments' side
    def vid_of(self, slot: str) -> str | None:
        """The vehicle of agent ``slot`` (None until it departed)."""
        d = self.driven.get(slot)
        return None if d is None else d.vid

    @property
    def ego_id(self) -> str | None:
        return self.vid_of(self.slots[0])

    def act(self, action: Any, slot: str = "ego") -> None:
        """Hold ``action`` for ``slot``'s vehicle from now on (a lane change is requested once)."""
        d = self.driven[slot]
        if self.p.action == "discrete":
            a = int(action)
            d.target = apply_meta(d.target, a, n_lanes=1)  # the speed; lanes: requests below
            d.lane_request = 1 if a == LANE_LEFT else -1 if a == LANE_RIGHT else 0
        else:
            d.action = np.clip(np.asarray(action, dtype=float).reshape(-1), -1.0, 1.0)
            if d.action.shape != (2,):
                raise ValueError(f"continuous action: expected 2 values, got {np.shape(action)}")
            lane = float(d.action[1])
            d.lane_request = 1 if lane > 0.5 else -1 if lane < -0.5 else 0

    def outcome(self, collided: bool, slot: str = "ego") -> tuple[float, bool, dict[str, Any]]:
        """The decision period's reward of ``slot``, whether it is done, and its terms."""
        p, d = self.p, self.driven[slot]
        speed01 = speed_reward(d.speed, *p.reward_speed_range_mps)
        reward = (p.collision_reward * collided + p.high_speed_reward * speed01
                  + p.lane_change_reward * d.changes + p.merged_reward * d.newly_merged)
        info = {"ego_speed_mps": d.speed, "ego_x_m": d.x, "ego_lane": d.lane,
                "ego_merged": int(d.merged), "crashed": bool(collided), "vid": d.vid}
        d.changes, d.newly_merged = 0, False
        return float(reward), d.gone or d.x >= self.lm.merge_end_x + p.goal_past_merge_m, info

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        if len(self.driven) < len(self.slots):
            self._pick(ctx)
        if not self.driven:
            return
        ids = np.asarray(ctx.snapshot.ids[r.sl])
        row_of = {str(v): k for k, v in enumerate(ids)}
        for d in self.driven.values():
            k = row_of.get(d.vid)
            d.gone = k is None
            if k is not None:
                self._observe(ctx, r, k, d)
                ctx.commands.extend(self._commands(ctx, r, k, d))

    def _pick(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        if ctx.t < self.p.ego_depart_s or len(r) == 0:
            return
        tb = r.tables
        chosen = {d.vid for d in self.driven.values()}
        if self.p.agents == 1:
            eligible = tb.role[r.uid] == Role.RAMP
        else:
            near = ctx.snapshot.position[r.sl, 0] >= self.lm.merge_start_x - self.p.agent_zone_m
            eligible = tb.connected[r.uid] & near
        cand = np.flatnonzero(eligible & (tb.depart_s[r.uid] >= self.p.ego_depart_s))
        for k in cand[np.argsort(r.uid[cand], kind="stable")]:
            vid = str(ctx.snapshot.ids[r.offset + k])
            if vid in chosen or len(self.driven) == len(self.slots):
                continue
            slot = self.slots[len(self.driven)]
            v = float(ctx.snapshot.speed[r.offset + k])
            target = MetaTarget(tuple(self.p.target_speeds_mps), nearest_speed_index(self.p.target_speeds_mps, v), 0)
            self.driven[slot] = Driven(vid, target, speed=v, x=float(ctx.snapshot.position[r.offset + k, 0]),
                                       ramp=bool(tb.role[r.uid[k]] == Role.RAMP))
            ctx.events.emit(ctx.t, self.name, "ego_agent", f"{vid} is the agent's vehicle {slot}", vid=vid, slot=slot)
            ctx.commands.append(SetLaneChangeMode(vid, AGENT_LANE_CHANGE_MODE))

    def _observe(self, ctx: RunContext, r: Any, k: int, d: Driven) -> None:
        row = r.offset + k
        d.speed, d.x = float(ctx.snapshot.speed[row]), float(ctx.snapshot.position[row, 0])
        lane = r.tables.lane_names[int(r.lane[k])]
        if lane.rsplit("_", 1)[0] == d.lane.rsplit("_", 1)[0] and lane != d.lane:
            d.changes += 1  # a lane change done (on the same edge), not merely requested
        d.lane = lane
        if d.ramp and not d.merged and self._on_mainline(lane):
            d.merged = d.newly_merged = True

    def _on_mainline(self, lane: str) -> bool:
        lm = self.lm
        return lane != lm.accel_lane and (lane.startswith(lm.merge_edge) or lane.startswith(lm.downstream_edge))

    def _commands(self, ctx: RunContext, r: Any, k: int, d: Driven) -> list[Any]:
        p, v, out = self.p, d.speed, []
        if p.action == "discrete":
            a_cmd = speed_control(v, d.target.speed_mps)
        else:
            a_cmd = continuous(d.action, (p.accel_range_mps2[0], -1.0), (p.accel_range_mps2[1], 1.0))[0]
        a_cmd = float(np.clip(a_cmd, *p.accel_range_mps2))
        gap, v_lead = self._leader(ctx, r, k)
        a = safe_accel(gap, v, v_lead, a_cmd, self.safety)
        self.caps += a < a_cmd
        out.append(SetSpeed(d.vid, max(0.0, v + a * self.period), p.command_speed_mode))
        if d.lane_request and not d.lane.startswith(":"):
            index = int(d.lane.rsplit("_", 1)[1]) + d.lane_request
            if index >= 0:  # an index the edge lacks is ignored by SUMO
                out.append(ChangeLane(d.vid, index, p.lane_change_s))
            d.lane_request = 0
        return out

    def _leader(self, ctx: RunContext, r: Any, k: int) -> tuple[float, float]:
        """Bumper-to-bumper gap [m] and speed [m/s] of the vehicle's leader on its lane (inf: none)."""
        lead = int(lane_leaders(r.lane, r.lane_pos)[k])
        if lead < 0:
            return math.inf, 0.0
        s = ctx.snapshot
        gap = float(r.lane_pos[lead] - s.size[r.offset + lead, 0] - r.lane_pos[k])
        return gap, float(s.speed[r.offset + lead])

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"ego_merged": sum(d.merged for d in self.driven.values()), "ego_safety_caps": self.caps}
