"""Builder ``rural_two_lane``: a straight two-way rural road, one lane per direction.

Two edges share the centreline y = 0 from x = 0 to x = ``length_m``: ``east`` (+x) and ``west`` (-x).
With SUMO's right-hand traffic each lane lies right of the centreline, so the eastbound lane centre is
at y = -w/2 and the westbound one at y = +w/2.  An overtaking ego on ``east`` that is placed on the
opposite lane with ``moveToXY`` therefore shifts by ``opposite_lane_offset_m`` = +w (to its left).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import sumolib
from pydantic import BaseModel, ConfigDict, Field

from corridor.traffic.networks.landmarks import RuralLandmarks
from corridor.traffic.networks.registry import BuildOutput, PlainNet, register_builder, run_netconvert


class RuralTwoLaneParams(BaseModel):
    """Length, speed limit and lane width of the rural road."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    length_m: float = Field(3000.0, gt=10)  # [m]
    speed_mps: float = Field(25.0, gt=0)  # [m/s]
    lane_width_m: float = Field(3.5, gt=2.0)  # [m]


def _plain(p: RuralTwoLaneParams) -> PlainNet:
    """Two nodes and the two opposite edges between them."""
    road = {
        "numLanes": 1,
        "speed": p.speed_mps,
        "width": p.lane_width_m,
        "spreadType": "right",
        "priority": 5,
    }
    return PlainNet(
        nodes=[
            {"id": "n_west", "x": 0.0, "y": 0.0, "type": "priority"},
            {"id": "n_east", "x": p.length_m, "y": 0.0, "type": "priority"},
        ],
        edges=[
            {"id": "east", "from": "n_west", "to": "n_east", **road},
            {"id": "west", "from": "n_east", "to": "n_west", **road},
        ],
    )


def _landmarks(p: RuralTwoLaneParams, net_file: Path) -> RuralLandmarks:
    """Lane ids and lateral geometry measured on the built network."""
    net = sumolib.net.readNet(str(net_file))
    east_y = float(np.mean(np.asarray(net.getLane("east_0").getShape())[:, 1]))
    west_y = float(np.mean(np.asarray(net.getLane("west_0").getShape())[:, 1]))
    return RuralLandmarks(
        east_edge="east", west_edge="west", east_lane="east_0", west_lane="west_0",
        east_lane_y=east_y, west_lane_y=west_y,  # [m]
        opposite_lane_offset_m=west_y - east_y,  # [m] to the LEFT of an eastbound vehicle (+y)
        lane_width_m=p.lane_width_m,
        length_m=float(net.getLane("east_0").getLength()),  # [m] as built
    )


@register_builder("rural_two_lane", RuralTwoLaneParams, RuralLandmarks)
def build_rural_two_lane(params: RuralTwoLaneParams, work_dir: Path) -> BuildOutput:
    """Build the two-way road into ``work_dir``."""
    net_file = run_netconvert(work_dir, _plain(params))
    return BuildOutput(
        additional_files=(),
        routes={"east": ("east",), "west": ("west",)},
        landmarks=_landmarks(params, net_file),
    )
