"""Builder ``highway_onramp``: a straight freeway along +x with one on-ramp and an acceleration lane.

Layout (SUMO x/y used as the local ENU frame, mainline from x = 0 along +x)::

    upstream [0, U]  ->  merge [U, U + A] (mainline lanes + acceleration lane 0)  ->  downstream [U + A, U + D]
                     ^
    ramp (length R) joins from below/right at a shallow angle at x = U

``downstream_length_m`` D is measured from the ramp nose, so the acceleration lane (length A) is the
first part of the downstream mainline; A < D is required.  The acceleration lane has no successor:
SUMO's strategic lane changing makes ramp vehicles leave it before its end.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import sumolib
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.traffic.networks.landmarks import OnrampLandmarks
from corridor.traffic.networks.registry import BuildOutput, PlainNet, register_builder, run_netconvert

MIN_RUNOUT_M = 50.0  # [m] mainline needed after the acceleration lane ends


class HighwayOnrampParams(BaseModel):
    """Geometry and speed limits of the on-ramp merge network."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    mainline_lanes: int = Field(2, ge=1, le=6)
    upstream_length_m: float = Field(1500.0, gt=0)  # [m] x = 0 to the ramp nose
    downstream_length_m: float = Field(1000.0, gt=0)  # [m] ramp nose to the end (includes merge section)
    ramp_length_m: float = Field(300.0, ge=20)  # [m]
    accel_lane_length_m: float = Field(200.0, gt=0)  # [m]
    mainline_speed_mps: float = Field(33.33, gt=0)  # [m/s]
    ramp_speed_mps: float = Field(22.22, gt=0)  # [m/s]
    lane_width_m: float = Field(3.5, gt=2.0)  # [m]
    ramp_angle_deg: float = Field(5.0, gt=0, lt=45)  # [deg] angle between ramp and mainline

    @model_validator(mode="after")
    def _accel_lane_fits(self) -> HighwayOnrampParams:
        if self.accel_lane_length_m + MIN_RUNOUT_M > self.downstream_length_m:
            raise ValueError(
                f"accel_lane_length_m ({self.accel_lane_length_m:g} m) must be at least {MIN_RUNOUT_M:g} m "
                f"shorter than downstream_length_m ({self.downstream_length_m:g} m), which contains it"
            )
        return self


def _plain(p: HighwayOnrampParams) -> PlainNet:
    """Nodes, edges and lane-to-lane connections of the merge."""
    u, a, d = p.upstream_length_m, p.accel_lane_length_m, p.downstream_length_m
    n, w = p.mainline_lanes, p.lane_width_m
    angle = math.radians(p.ramp_angle_deg)
    accel_y = -(n + 0.5) * w  # [m] centre of the acceleration lane (lanes spread right of y = 0)
    ramp_start = (u - p.ramp_length_m * math.cos(angle), accel_y - p.ramp_length_m * math.sin(angle))
    plain = PlainNet()
    plain.nodes = [
        {"id": "n_up", "x": 0.0, "y": 0.0, "type": "priority"},
        {"id": "n_merge", "x": u, "y": 0.0, "type": "priority"},
        {"id": "n_merge_end", "x": u + a, "y": 0.0, "type": "priority"},
        {"id": "n_down", "x": u + d, "y": 0.0, "type": "priority"},
        {"id": "n_ramp", "x": ramp_start[0], "y": ramp_start[1], "type": "priority"},
    ]
    main = {"priority": 10, "speed": p.mainline_speed_mps, "width": w, "spreadType": "right"}
    plain.edges = [
        {"id": "upstream", "from": "n_up", "to": "n_merge", "numLanes": n, **main},
        {"id": "merge", "from": "n_merge", "to": "n_merge_end", "numLanes": n + 1, **main},
        {"id": "downstream", "from": "n_merge_end", "to": "n_down", "numLanes": n, **main},
        {
            "id": "ramp",
            "from": "n_ramp",
            "to": "n_merge",
            "numLanes": 1,
            "priority": 5,
            "speed": p.ramp_speed_mps,
            "width": w,
            "spreadType": "center",
            "shape": [ramp_start, (u, accel_y)],
        },
    ]
    plain.connections = [
        *({"from": "upstream", "to": "merge", "fromLane": i, "toLane": i + 1} for i in range(n)),
        {"from": "ramp", "to": "merge", "fromLane": 0, "toLane": 0},
        *({"from": "merge", "to": "downstream", "fromLane": i + 1, "toLane": i} for i in range(n)),
    ]
    return plain


def _landmarks(p: HighwayOnrampParams, net_file: Path) -> OnrampLandmarks:
    """Named facts measured on the built network (netconvert trims edges at junctions)."""
    net = sumolib.net.readNet(str(net_file))
    accel = np.asarray(net.getLane("merge_0").getShape())
    merge_start_x, merge_end_x = float(accel[0, 0]), float(accel[-1, 0])
    return OnrampLandmarks(
        upstream_edge="upstream", merge_edge="merge", downstream_edge="downstream", ramp_edge="ramp",
        accel_lane="merge_0",
        join_lanes=("upstream_0", "merge_1"),  # lane 0 upstream, lane 1 beside the acceleration lane
        merge_junction="n_merge", mainline_lanes=p.mainline_lanes, lane_width_m=p.lane_width_m,
        ramp_angle_deg=p.ramp_angle_deg,
        merge_start_x=merge_start_x,  # [m] start of the acceleration lane
        merge_end_x=merge_end_x,  # [m] end of the acceleration lane
        past_merge_x=merge_end_x,  # [m] a vehicle with x beyond this has merged (or failed to)
        mainline_end_x=float(net.getEdge("downstream").getShape()[-1][0]),  # [m]
        accel_lane_length_m=float(net.getLane("merge_0").getLength()),  # [m] as built
    )


@register_builder("highway_onramp", HighwayOnrampParams, OnrampLandmarks)
def build_highway_onramp(params: HighwayOnrampParams, work_dir: Path) -> BuildOutput:
    """Build the merge network into ``work_dir``."""
    net_file = run_netconvert(work_dir, _plain(params))
    routes = {"main": ("upstream", "merge", "downstream"), "ramp": ("ramp", "merge", "downstream")}
    return BuildOutput(additional_files=(), routes=routes, landmarks=_landmarks(params, net_file))
