"""A network builder as a plug-in: ``example_ring``, a one-lane ring road of ``n`` straight edges,
registered with corridor when this module is imported (the ``corridor.networks`` entry point)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from corridor.traffic.networks.landmarks import Landmarks
from corridor.traffic.networks.registry import BuildOutput, PlainNet, register_builder, run_netconvert


class RingParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    radius_m: float = Field(100.0, gt=10)  # [m]
    edges: int = Field(4, ge=3, le=32)
    speed_mps: float = Field(13.9, gt=0)  # [m/s]


class RingLandmarks(Landmarks):
    kind: Literal["example_ring"] = "example_ring"
    circumference_m: float  # [m] of the polygon through the nodes


@register_builder("example_ring", RingParams, RingLandmarks)
def build_ring(params: RingParams, work_dir: Path) -> BuildOutput:
    n, r = params.edges, params.radius_m
    plain = PlainNet()
    for k in range(n):
        a = 2 * math.pi * k / n
        plain.nodes.append({"id": f"n{k}", "x": r * math.cos(a), "y": r * math.sin(a), "type": "priority"})
    for k in range(n):
        plain.edges.append({"id": f"e{k}", "from": f"n{k}", "to": f"n{(k + 1) % n}", "numLanes": 1,
                            "speed": params.speed_mps})
    run_netconvert(work_dir, plain)
    edges = tuple(f"e{k}" for k in range(n))
    return BuildOutput(additional_files=(), routes={"loop": edges[:-1]},
                       landmarks=RingLandmarks(lane_width_m=3.2, circumference_m=2 * n * r * math.sin(math.pi / n)))
