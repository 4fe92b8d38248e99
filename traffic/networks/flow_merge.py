"""Builder ``flow_merge``: the network of Flow's merge benchmark (``flow/benchmarks/merge0.py``-``merge2.py``,
``flow.networks.MergeNetwork``), rebuilt with netconvert.

A single-lane highway along +x and a single-lane on-ramp that joins it at a junction (no acceleration
lane), the edge names Flow uses::

    inflow_highway [0, I] -> left [I, I + P] -> (junction "center") -> center [I + P, I + P + Q]
                                        ^
    inflow_merge (I) -> bottom (M) -----+   the ramp comes in from below at 45 degrees

I = 100 m inflow edges, P = 500 m of highway before the merge (``pre_merge_length``), M = 100 m merge
edge, Q = 100 m after the merge; 30 m/s everywhere.  Flow gives the junction a 10 m radius and leaves
the edge priorities equal; netconvert then makes the *ramp* the major road at the junction (link state
"M", the highway "m"), which Flow's humans never notice: they drive speed mode 1 ("obey_safe_speed"),
without right-of-way checks.  Here the highway has the higher priority (3 against 1), so drivers who
respect the right of way (the calibrated humans) yield on the ramp, as at a real on-ramp.
"""

from __future__ import annotations

import math
from pathlib import Path

import sumolib
from pydantic import BaseModel, ConfigDict, Field

from corridor.traffic.networks.landmarks import FlowMergeLandmarks
from corridor.traffic.networks.registry import BuildOutput, PlainNet, register_builder, run_netconvert

HIGHWAY = ("inflow_highway", "left", "center")
RAMP = ("inflow_merge", "bottom", "center")


class FlowMergeParams(BaseModel):
    """Geometry of Flow's merge network (defaults: the benchmark's values)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    inflow_length_m: float = Field(100.0, gt=0)  # [m] Flow's INFLOW_EDGE_LEN (both inflow edges)
    pre_merge_length_m: float = Field(500.0, gt=0)  # [m] highway before the merge (benchmarks: 500)
    merge_length_m: float = Field(100.0, gt=0)  # [m] the ramp's merge edge
    post_merge_length_m: float = Field(100.0, gt=0)  # [m] highway after the merge
    speed_limit_mps: float = Field(30.0, gt=0)  # [m/s]
    ramp_angle_deg: float = Field(45.0, gt=0, lt=90)  # [deg] Flow: pi / 4
    junction_radius_m: float = Field(10.0, ge=0)  # [m] Flow's "center" node radius
    lane_width_m: float = Field(3.2, gt=2.0)  # [m] SUMO's default lane width (Flow sets none)


def _plain(p: FlowMergeParams) -> PlainNet:
    """Flow's nodes and edges, shifted by the inflow length so the highway starts at x = 0."""
    i, pre, m = p.inflow_length_m, p.pre_merge_length_m, p.merge_length_m
    cx = i + pre  # [m] the merge junction
    c, s = math.cos(math.radians(p.ramp_angle_deg)), math.sin(math.radians(p.ramp_angle_deg))
    plain = PlainNet()
    plain.nodes = [
        {"id": "inflow_highway", "x": 0.0, "y": 0.0, "type": "priority"},
        {"id": "left", "x": i, "y": 0.0, "type": "priority"},
        {"id": "center", "x": cx, "y": 0.0, "type": "priority", "radius": p.junction_radius_m},
        {"id": "right", "x": cx + p.post_merge_length_m, "y": 0.0, "type": "priority"},
        {"id": "inflow_merge", "x": cx - (m + i) * c, "y": -(m + i) * s, "type": "priority"},
        {"id": "bottom", "x": cx - m * c, "y": -m * s, "type": "priority"},
    ]
    lane = {"numLanes": 1, "speed": p.speed_limit_mps, "width": p.lane_width_m}
    highway, ramp = {**lane, "priority": 3}, {**lane, "priority": 1}
    plain.edges = [
        {"id": "inflow_highway", "from": "inflow_highway", "to": "left", **highway},
        {"id": "left", "from": "left", "to": "center", **highway},
        {"id": "center", "from": "center", "to": "right", **highway},
        {"id": "inflow_merge", "from": "inflow_merge", "to": "bottom", **ramp},
        {"id": "bottom", "from": "bottom", "to": "center", **ramp},
    ]
    return plain


def _landmarks(p: FlowMergeParams, net_file: Path) -> FlowMergeLandmarks:
    """x positions measured on the built network (netconvert trims edges at the junction)."""
    net = sumolib.net.readNet(str(net_file))
    return FlowMergeLandmarks(
        lane_width_m=p.lane_width_m, highway_edges=HIGHWAY, ramp_edges=RAMP[:2], post_merge_edge="center",
        merge_junction="center",
        mainline_start_x=float(net.getLane("inflow_highway_0").getShape()[0][0]),  # [m]
        merge_x=float(net.getLane("left_0").getShape()[-1][0]),  # [m]
        past_merge_x=float(net.getLane("center_0").getShape()[0][0]),  # [m]
        mainline_end_x=float(net.getLane("center_0").getShape()[-1][0]),  # [m]
        ramp_angle_deg=p.ramp_angle_deg,
    )


@register_builder("flow_merge", FlowMergeParams, FlowMergeLandmarks)
def build_flow_merge(params: FlowMergeParams, work_dir: Path) -> BuildOutput:
    """Build Flow's merge network into ``work_dir``."""
    net_file = run_netconvert(work_dir, _plain(params))
    return BuildOutput(additional_files=(), routes={"main": HIGHWAY, "ramp": RAMP},
                       landmarks=_landmarks(params, net_file))
