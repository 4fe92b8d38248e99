"""The ego vehicle in SUMO: a kinematic bicycle integrated by corridor and placed into SUMO every step.

Why a backend of its own: the ego's dynamics are corridor's (the shared ``f(x, u, p)`` with RK4 from
``controllers.bicycle``, the very model the MPC plans with), not SUMO's car-following model.  SUMO only
*shows* the ego to its traffic: the ego is inserted with ``vehicle.add`` (id ``ego``) and, right before
every ``simulationStep`` (the SUMO backend's ``pre_step`` hook), integrated by one step and put at its
new pose with ``moveToXY`` (keepRoute=2, SUMO angle = 90 - degrees(yaw), front-bumper position).  So
after the step SUMO's row of the ego and every SUMO vehicle refer to the same instant, SUMO traffic
reacts to the ego (followers brake for it, it is a leader on whichever lane it is mapped to), and
SUMO's collision check sees it (its SUMO length and width are set to the bicycle's box).

The snapshot holds the ego once: this backend emits no snapshot part; the SUMO row stands for it and
is marked ``Role.CONTROLLED``, which makes the kernel's collision monitor box-check it against every
other entity; SUMO's own report of a pair with the ego is only logged (SUMO checks the ego as a box
aligned with its lane, which is wrong while it stands at an angle to the lane, e.g. parking).

Coupling to SUMO goes only through the SUMO backend's documented seam (no libsumo, no backend
state): its ``pre_step`` hook, ``apply`` with commands that carry ``apply_to_sumo`` (``InsertEgo``,
``PlaceVehicle``), ``snapshot_part()`` (is the ego on the road yet / still), ``vehicle_pose`` (SUMO's
insertion pose, read once: the snapshot holds the box centre, and re-deriving the front bumper from
it would not be bit-identical) and ``mark_controlled``.  The ego is placed inside the SUMO step (not
through the command bus of the *act* phase) because the bicycle is integrated there, after SUMO's
previous step, with the input of this tick.

Inputs arrive on the command bus as ``EgoInput`` (zero-order hold until the next one).  Other vehicles
of the scenario that must start next to the ego (the slow lead, close followers) are inserted with it
(``companions``), SUMO-driven, with an optional maximum speed (``vehicle.setMaxSpeed``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Backend, Metric, Need, RunContext
from corridor.traffic.sumo.backend import SumoBackend
from corridor.vehicles.ground.bicycle import BicycleParams, clip_input, rk4_step

SPEED_MODE_NONE = 0  # SUMO speed mode without any safety check (corridor owns the dynamics)
LANE_CHANGE_MODE_NONE = 0  # no autonomous lane changes by SUMO


@dataclass(frozen=True)
class EgoInput:
    """Longitudinal acceleration [m/s^2] and front steering angle [rad] for the ego ``vid``."""

    vid: str
    accel_mps2: float
    steer_rad: float


@dataclass(frozen=True)
class PlaceVehicle:
    """Put ``vid``'s front bumper at (x, y) [m] with SUMO angle ``angle_deg`` (moveToXY, keepRoute=2)."""

    vid: str
    x: float
    y: float
    angle_deg: float

    def apply_to_sumo(self, ls: Any) -> None:
        ls.vehicle.moveToXY(self.vid, "", -1, self.x, self.y, self.angle_deg, 2)


@dataclass(frozen=True)
class InsertEgo:
    """Queue the ego (SUMO box = the bicycle's, no SUMO safety checks or lane changes) and its
    companions for insertion at ``depart_s``."""

    p: Any  # EgoBicycle.Params

    def apply_to_sumo(self, ls: Any) -> None:
        p = self.p
        depart = f"{p.depart_s:g}"
        ls.vehicle.add(p.vid, p.route, typeID=p.vtype, depart=depart, departLane="0",
                       departPos=f"{p.depart_pos_m:g}", departSpeed=f"{p.depart_speed_mps:g}")
        ls.vehicle.setLength(p.vid, p.bicycle.length_m)  # SUMO's box = the bicycle's box
        ls.vehicle.setWidth(p.vid, p.bicycle.width_m)
        ls.vehicle.setSpeedMode(p.vid, SPEED_MODE_NONE)
        ls.vehicle.setLaneChangeMode(p.vid, LANE_CHANGE_MODE_NONE)
        for cid, c in p.companions.items():
            speed = c.speed_mps if c.max_speed_mps is None else min(c.speed_mps, c.max_speed_mps)
            ls.vehicle.add(cid, c.route, typeID=c.vtype, depart=depart, departLane="0",
                           departPos=f"{max(p.depart_pos_m + c.offset_m, 0.0):g}", departSpeed=f"{speed:g}")
            if c.max_speed_mps is not None:
                ls.vehicle.setMaxSpeed(cid, c.max_speed_mps)


class CompanionSpec(BaseModel):
    """A SUMO-driven vehicle inserted together with the ego, ``offset_m`` ahead of it along its route."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    route: str = "east"
    vtype: str = "car"
    offset_m: float = 30.0  # [m] front bumper relative to the ego's front bumper (negative: behind)
    speed_mps: float = Field(15.0, ge=0.0)  # [m/s] at insertion (at most max_speed_mps)
    max_speed_mps: float | None = Field(None, gt=0.0)  # [m/s] vehicle.setMaxSpeed (None: the vType's)


class EgoBicycle(Backend):
    """A kinematic-bicycle ego driven by ``EgoInput`` commands and mirrored into SUMO each step.

    ``state`` is the rear-axle state ``(x [m], y [m], yaw [rad], v [m/s])`` in the ENU frame (SUMO x/y);
    ``active`` tells whether the ego is on the road (it departs at ``depart_s``).
    """

    needs: ClassVar[dict[str, Need]] = {
        "sumo": Need(role="road", hint="the ego bicycle needs a road (SUMO) backend: add `road:`")}
    provides: ClassVar[frozenset[str]] = frozenset({"ego"})
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('ego_departed_s', 's',
               'Time the ego entered the road.'),
        Metric('ego_final_x_m', 'm',
               "The ego's east coordinate at the end."),
    )
    period_source: ClassVar[str | None] = "peer:sumo"  # [s] SUMO's step (the ego is integrated inside it)
    sumo: SumoBackend

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        vid: str = "ego"
        route: str = "east"
        vtype: str = "ego"  # a vehicle type of road.demand.vehicle_types (SUMO's view: decel, ...)
        depart_s: float = Field(0.0, ge=0.0)  # [s]
        depart_pos_m: float = Field(100.0, ge=0.0)  # [m] front bumper along the route
        depart_speed_mps: float = Field(15.0, ge=0.0)  # [m/s]
        bicycle: BicycleParams = BicycleParams()
        companions: dict[str, CompanionSpec] = Field(default_factory=dict)
        allow_reverse: bool = False  # a negative acceleration at standstill drives backwards (parking)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.vid = params.vid
        self.state = np.zeros(4)
        self.active = False
        self.departed_s = math.nan
        self._u = np.zeros(2)

    # ------------------------------------------------------------------ set-up
    def setup(self, ctx: RunContext) -> None:
        sumo = self.sumo
        if abs(sumo.period - self.period) > 1e-9:  # a scenario's period: override
            raise ValueError(f"{self.name}: period {self.period} s must equal SUMO's step {sumo.period} s")
        sumo.pre_step.append(self._pre_step)
        sumo.apply([InsertEgo(self.p)], ctx)

    def _on_road(self) -> bool:
        return bool(np.any(self.sumo.snapshot_part().ids == self.vid))

    # ------------------------------------------------------------------ the step
    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        for c in commands:
            if isinstance(c, EgoInput) and c.vid == self.vid:
                self._u = np.array([c.accel_mps2, c.steer_rad], dtype=float)

    def _pre_step(self, ctx: RunContext) -> None:
        """Before SUMO's step: start from SUMO's insertion pose once, else integrate; then place."""
        sumo = self.sumo
        if not self.active:
            if not self._on_road():
                return
            self._start(ctx.t)
        self.state = rk4_step(self.state, clip_input(self._u, self.p.bicycle), self.period, self.p.bicycle)
        if not self.p.allow_reverse:
            self.state[3] = max(float(self.state[3]), 0.0)  # brakes stop the car, never reverse it
        fx, fy = self.front_bumper()
        sumo.apply([PlaceVehicle(self.vid, fx, fy, 90.0 - math.degrees(float(self.state[2])))], ctx)

    def _start(self, t_s: float) -> None:
        """Take over the ego where SUMO inserted it (front bumper and angle -> rear axle)."""
        fx, fy, angle_deg, speed = self.sumo.vehicle_pose(self.vid)
        yaw = math.radians(90.0 - angle_deg)
        back = 0.5 * self.p.bicycle.length_m + 0.5 * self.p.bicycle.wheelbase_m  # front bumper -> rear axle
        self.state = np.array([fx - back * math.cos(yaw), fy - back * math.sin(yaw), yaw, speed])
        self.active, self.departed_s = True, t_s
        self.sumo.mark_controlled(self.vid)  # SUMO row = the ego: role CONTROLLED, box-checked

    def front_bumper(self) -> tuple[float, float]:
        """ENU (x, y) [m] of the front bumper centre, the point SUMO positions vehicles by."""
        x, y, yaw, _ = self.state
        ahead = 0.5 * self.p.bicycle.wheelbase_m + 0.5 * self.p.bicycle.length_m
        return float(x + ahead * math.cos(yaw)), float(y + ahead * math.sin(yaw))

    def tick(self, ctx: RunContext) -> None:
        """After SUMO's step: notice when the ego left the network (end of its route)."""
        if self.active and self.sumo is not None and not self._on_road():
            self.active = False
            ctx.events.emit(ctx.t, self.name, "ego_left", f"{self.vid} left the network")

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"ego_departed_s": self.departed_s, "ego_final_x_m": float(self.state[0])}

