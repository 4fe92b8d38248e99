"""Builder ``parking_street``: a straight two-way street with on-street parking bays and parked cars.

Two edges share the centreline y = 0 from x = 0 to ``length_m``: ``east`` (+x, ``east_lanes`` lanes, so
through traffic can pass a car that stops to park) and ``west`` (-x, one lane); right-hand traffic, so
the eastbound lanes lie at y < 0.  Right of the rightmost eastbound lane ``east_0`` (the kerb line)
lies a row of ``bays`` parking bays from ``first_bay_x`` on, each its own SUMO
``parkingArea`` on ``east_0`` with one explicit ``space`` (position and angle given, so the bay is
where the landmarks say): ``layout: parallel`` bays are ``bay_length_m`` along the street and
``bay_depth_m`` deep, cars parked along the street; ``perpendicular`` bays are ``bay_length_m`` wide
(along the street) and ``bay_depth_m`` deep, cars parked facing the street (heading +y, as SUMO parks them).  SUMO positions
a parked car by its front bumper: each space is given at the bay centre + half a car length ahead.

Occupancy is drawn here, from ``occupancy_seed`` (a scenario randomises it per run): each bay is taken
with probability ``occupancy`` by a SUMO vehicle inserted at t = 0 at its stop (``departPos="stop"``,
``stop parkingArea=... parking=true``): parked from the first step for the rest of the run; the
additional file holds its vType, so the parked cars are SUMO's own vehicles at SUMO's parking positions.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np
import sumolib
from pydantic import BaseModel, ConfigDict, Field

from corridor.traffic.networks.landmarks import StreetParkingLandmarks
from corridor.traffic.networks.registry import (
    BuildOutput,
    PlainNet,
    element,
    register_builder,
    run_netconvert,
    write_xml,
)

PARKED_LENGTH_M, PARKED_WIDTH_M = 4.5, 1.8  # [m] the parked cars' vType


class ParkingStreetParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    length_m: float = Field(260.0, gt=50.0)  # [m]
    speed_mps: float = Field(13.9, gt=0.0)  # [m/s]
    lane_width_m: float = Field(3.5, gt=2.0)  # [m]
    east_lanes: int = Field(2, ge=1, le=3)
    layout: Literal["parallel", "perpendicular"] = "parallel"
    bays: int = Field(16, ge=1, le=60)
    first_bay_x: float = Field(60.0, ge=20.0)  # [m] start of the first bay
    bay_length_m: float = Field(6.5, gt=2.0, le=10.0)  # [m] along the street
    bay_depth_m: float = Field(2.2, gt=1.8, le=7.0)  # [m] across
    occupancy: float = Field(0.7, ge=0.0, le=1.0)  # probability that a bay is taken
    occupancy_seed: int = Field(0, ge=0)


def _plain(p: ParkingStreetParams) -> PlainNet:
    road = {"numLanes": 1, "speed": p.speed_mps, "width": p.lane_width_m, "spreadType": "right", "priority": 5}
    return PlainNet(
        nodes=[{"id": "n_west", "x": 0.0, "y": 0.0, "type": "priority"},
               {"id": "n_east", "x": p.length_m, "y": 0.0, "type": "priority"}],
        edges=[{"id": "east", "from": "n_west", "to": "n_east", **{**road, "numLanes": p.east_lanes}},
               {"id": "west", "from": "n_east", "to": "n_west", **road}])


def bay_geometry(p: ParkingStreetParams, kerb_y: float) -> tuple[np.ndarray, float]:
    """Bay centres (n, 2) [m] and the parked cars' heading [rad] (ENU)."""
    x = p.first_bay_x + (np.arange(p.bays) + 0.5) * p.bay_length_m
    y = np.full(p.bays, kerb_y - 0.5 * p.bay_depth_m)
    return np.column_stack([x, y]), (0.0 if p.layout == "parallel" else 0.5 * math.pi)


def _additional(p: ParkingStreetParams, centres: np.ndarray, heading: float, taken: np.ndarray) -> list[str]:
    # SUMO's navigational angle of the space; SUMO 1.28 reports a car parked in a space of angle 180
    # with angle 0 (and one of angle 0 with 180) while a space of angle 90 keeps 90: the perpendicular
    # space is given turned by 180 deg so that the parked car's reported angle is the intended one
    # (a test reads the parked cars back)
    angle_deg = (90.0 - math.degrees(heading)) % 360.0 + (180.0 if p.layout == "perpendicular" else 0.0)
    out = [element("vType", {"id": "parked", "length": PARKED_LENGTH_M, "width": PARKED_WIDTH_M,
                             "minGap": 0.5, "accel": 2.0, "decel": 4.5, "sigma": 0.0})]
    ahead = 0.5 * PARKED_LENGTH_M * np.array([math.cos(heading), math.sin(heading)])
    for k, (cx, cy) in enumerate(centres):
        start = cx - 0.5 * p.bay_length_m
        space = element("space", {"x": cx + ahead[0], "y": cy + ahead[1], "width": PARKED_WIDTH_M + 0.2,
                                  "length": PARKED_LENGTH_M + 0.5, "angle": angle_deg})
        out.append(element("parkingArea", {"id": f"bay{k}", "lane": "east_0", "startPos": start,
                                           "endPos": start + p.bay_length_m, "roadsideCapacity": 0}, [space]))
    for k in np.flatnonzero(taken):
        start = centres[k, 0] - 0.5 * p.bay_length_m
        stop = element("stop", {"parkingArea": f"bay{k}", "duration": 1e6, "parking": "true"})
        out.append(element("vehicle", {"id": f"parked{k}", "type": "parked", "depart": 0.0,
                                       "departPos": "stop", "departSpeed": 0.0},
                           [element("route", {"edges": "east"}), stop]))
    return out


def _landmarks(p: ParkingStreetParams, net_file: Path, centres: np.ndarray, heading: float,
               taken: np.ndarray) -> StreetParkingLandmarks:
    net = sumolib.net.readNet(str(net_file))
    east_y = float(np.mean(np.asarray(net.getLane("east_0").getShape())[:, 1]))
    kerb_y = east_y - 0.5 * p.lane_width_m
    return StreetParkingLandmarks(
        lane_width_m=p.lane_width_m, east_edge="east", west_edge="west", east_lane="east_0",
        east_lane_y=east_y, kerb_y=kerb_y, layout=p.layout, bay_length_m=p.bay_length_m,
        bay_depth_m=p.bay_depth_m, bay_x=tuple(float(x) for x in centres[:, 0]),
        bay_y=float(centres[0, 1]), parked_heading=heading, taken=tuple(bool(t) for t in taken),
        length_m=float(net.getLane("east_0").getLength()), end_x=float(p.length_m - 10.0))


@register_builder("parking_street", ParkingStreetParams, StreetParkingLandmarks)
def build_parking_street(params: ParkingStreetParams, work_dir: Path) -> BuildOutput:
    net_file = run_netconvert(work_dir, _plain(params))
    net = sumolib.net.readNet(str(net_file))
    east_y = float(np.mean(np.asarray(net.getLane("east_0").getShape())[:, 1]))
    centres, heading = bay_geometry(params, east_y - 0.5 * params.lane_width_m)
    rng = np.random.default_rng(params.occupancy_seed)
    taken = rng.random(params.bays) < params.occupancy
    write_xml(work_dir / "parking.add.xml", "additional", _additional(params, centres, heading, taken))
    return BuildOutput(additional_files=("parking.add.xml",), routes={"east": ("east",), "west": ("west",)},
                       landmarks=_landmarks(params, net_file, centres, heading, taken))
