"""The overtaking controller in a SUMO run: the ``overtaking`` component around ``OvertakingController``.

Each period it builds the controller's observation from the world snapshot in the road frame of
``overtaking_mpc`` (x along the eastbound road, own lane centre y = 0, oncoming lane y = +lane width):
the nearest own-lane vehicle ahead (lead), the oncoming vehicles and the own-lane vehicles behind
(followers), each sensed within ``sensor_range_m`` with Gaussian position/speed noise; the controller's
filterpy predictor tracks them.  The ego's own state comes from the ego backend (odometry, exact).  It
puts an ``EgoInput`` on the bus for the ego backend.

It records no signal: the ones the STL specs of ``scenarios/overtaking.yaml`` judge (``gap_lead``,
``lane_offset``, ``clearance``, ...) and ``min_gap_lead_m`` / ``min_gap_oncoming_m`` are measured by the
``overtaking_safety`` monitor (``corridor.analysis.monitoring.overtaking``), so a baseline controller in its
place is judged on the same signals.  ``finish`` returns the controller's own metrics (outcome, modes,
re-plans, solve times).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.overtaking.controller import (
    OvertakingController,
    OvertakingObservation,
    OvertakingParams,
    VehicleObs,
)
from corridor.controllers.overtaking.mpc import body_centre
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.snapshot import WorldSnapshot
from corridor.traffic.networks.landmarks import RuralLandmarks
from corridor.traffic.sumo.trips import road_frame
from corridor.vehicles.ground.ego_bicycle import EgoBicycle, EgoInput


class OvertakingSumo(Controller):
    """Drives the ego bicycle of backend ``ego`` with the event-triggered STL overtaking MPC."""

    needs: ClassVar[dict[str, Need]] = {"ego": Need(role="ego", name_at="p.ego")}
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('overtake_success', '1',
               '1 if the ego passed the lead vehicle and returned to its lane.'),
        Metric('outcome', 'text',
               'passed, aborted or stayed.'),
        Metric('final_mode', 'text',
               "The overtaking automaton's mode at the end."),
        Metric('completion_time_s', 's',
               'From the last commit to pass to the end of the return (following again, in front of the lead).'),
        Metric('aborts', '1',
               'Aborted passes.'),
        Metric('replans', '1',
               'MPC re-plans.'),
        Metric('replans_every_step', '1',
               'Steps the controller was active (re-plans if it planned every step).'),
        Metric('replan_savings', '1',
               'Share of the active steps that needed no re-plan.'),
        Metric('solve_p50_ms', 'ms',
               'Median MPC solve time.'),
        Metric('solve_p95_ms', 'ms',
               '95th percentile MPC solve time.'),
        Metric('solve_max_ms', 'ms',
               'Longest MPC solve time.'),
        Metric('fallbacks', '1',
               'Steps that fell back to the safe command.'),
        Metric('controller_period_ms', 'ms',
               "The controller's period."),
    )
    period_source: ClassVar[str | None] = "p.controller.period_s"
    ego: EgoBicycle

    class Params(BaseModel):
        model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

        ego: str = "ego"  # name of the EgoBicycle backend component (it drives east, on route ``east``)
        sensor_range_m: float = Field(400.0, gt=0.0)  # [m]
        sensor_pos_noise_m: float = Field(0.3, ge=0.0)  # [m] 1-sigma
        sensor_speed_noise_mps: float = Field(0.2, ge=0.0)  # [m/s] 1-sigma
        controller: OvertakingParams = Field(default_factory=OvertakingParams)  # typed: a wrong nested key fails at load

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.cparams = params.controller
        self.ctrl: OvertakingController | None = None
        self.steps_active = 0  # controller periods with the ego on the road (= every-step re-plans)

    # ------------------------------------------------------------------ set-up
    def setup(self, ctx: RunContext) -> None:
        ego = self.ego
        marks = road_frame(ctx).tables.landmarks
        if not isinstance(marks, RuralLandmarks):
            raise ValueError(f"{self.name}: overtaking needs the rural two-lane road, not {marks.kind!r}")
        self.vid = ego.vid
        self.lane_y = float(marks.east_lane_y)  # [m] ENU y of the own lane centre
        road = self.cparams.road.model_copy(update={"lane_width_m": abs(float(marks.opposite_lane_offset_m))})
        self.cparams = self.cparams.model_copy(update={"ego": ego.p.bicycle, "road": road})
        self.ctrl = OvertakingController(self.cparams, ctx.events, name=self.vid)
        super().setup(ctx)

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        if self.ctrl is not None:
            self.ctrl.reset(rng)

    # ------------------------------------------------------------------ observe / step
    def _road_frame(self, s: WorldSnapshot) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Ids, body-centre x [m], y [m] and signed speed along the road [m/s] of everyone but the ego."""
        keep = s.ids != self.vid
        return s.ids[keep], s.position[keep, 0], s.position[keep, 1] - self.lane_y, s.velocity[keep, 0]

    def ego_road_state(self) -> np.ndarray:
        """The ego's rear-axle state in the road frame (ENU shifted by the own lane's centre y)."""
        x, y, yaw, v = self.ego.state
        return np.array([x, y - self.lane_y, yaw, v])

    def observe(self, ctx: RunContext) -> OvertakingObservation | None:
        if not self.ego.active:
            return None
        ego = self.ego_road_state()
        xc = float(body_centre(ego, self.cparams.ego.wheelbase_m)[0][0])
        ids, x, y, v = self._road_frame(ctx.snapshot)
        near = np.abs(x - xc) < self.p.sensor_range_m
        own = near & (v >= 0.0) & (y < 0.5 * self.cparams.road.lane_width_m)
        onc = near & (v < 0.0)
        ahead = own & (x > xc)
        behind = own & (x <= xc)
        lead = None
        if ahead.any():
            k = int(np.flatnonzero(ahead)[np.argmin(x[ahead])])
            lead = self._sense(ids[k], x[k], v[k])
        oncoming = tuple(self._sense(ids[k], x[k], v[k]) for k in np.flatnonzero(onc))
        followers = tuple(self._sense(ids[k], x[k], v[k]) for k in np.flatnonzero(behind))
        return OvertakingObservation(ctx.t, ego, lead, oncoming, followers)

    def _sense(self, vid: Any, x_m: float, v_mps: float) -> VehicleObs:
        return VehicleObs(str(vid), float(x_m + self.rng.normal(0.0, self.p.sensor_pos_noise_m)),
                          float(v_mps + self.rng.normal(0.0, self.p.sensor_speed_noise_mps)))

    def step(self, obs: OvertakingObservation | None) -> list[Any]:
        if obs is None or self.ctrl is None:
            return []
        self.steps_active += 1
        cmd = self.ctrl.step(obs)
        return [EgoInput(self.vid, cmd.accel_mps2, cmd.steer_rad)]

    # ------------------------------------------------------------------ metrics
    def finish(self, ctx: RunContext) -> dict[str, Any]:
        assert self.ctrl is not None
        c = self.ctrl
        jumps = [(t, src, dst) for t, src, dst, _ in c.ha.history]
        commits = [t for t, _, dst in jumps if dst == "pass"]
        done = [t for t, src, dst in jumps if src == "return" and dst == "follow"]
        aborts = sum(1 for _, _, dst in jumps if dst == "abort")
        outcome = "passed" if done else ("aborted" if aborts else "stayed")
        first_commit_before = [t for t in commits if done and t <= done[0]]
        solve_ms = 1e3 * np.asarray(c.solve_times) if c.solve_times else np.full(1, np.nan)
        return {
            "overtake_success": int(bool(done)),  # 0/1 (a number, so the report can plot its mean)
            "outcome": outcome,
            "final_mode": c.mode,
            "completion_time_s": done[0] - first_commit_before[-1] if first_commit_before else math.nan,
            "aborts": aborts,
            "replans": c.replans,
            "replans_every_step": self.steps_active,
            "replan_savings": 1.0 - c.replans / self.steps_active if self.steps_active else math.nan,
            "solve_p50_ms": float(np.percentile(solve_ms, 50)),
            "solve_p95_ms": float(np.percentile(solve_ms, 95)),
            "solve_max_ms": float(np.max(solve_ms)),
            "fallbacks": c.fallbacks,
            "controller_period_ms": 1e3 * self.period,
        }
