"""Typed, frozen landmarks of the generated road networks (what controllers and monitors may know
about a network without reading lane-name strings): one pydantic model per builder, stored as JSON
in the network cache (``parse_landmarks`` reads it back by ``kind``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Landmarks(_Frozen):
    """Facts every network has."""

    kind: str
    lane_width_m: float  # [m]

    def declared_detectors(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """(induction loops, lane-area detectors, watched edges) a road backend reads each step."""
        return (), (), ()

    def x(self, name: str) -> float:
        """A named position [m] (a field ending in ``_x``), for monitors configured by landmark name."""
        if not name.endswith("_x") or name not in type(self).model_fields:
            xs = sorted(f for f in type(self).model_fields if f.endswith("_x"))
            raise ValueError(f"unknown landmark {name!r} of network {self.kind!r}; positions: {', '.join(xs)}")
        return float(getattr(self, name))


class OnrampLandmarks(Landmarks):
    """``highway_onramp``: a mainline along +x, one on-ramp and its acceleration lane (lane 0 of the
    merge edge); x positions measured on the built network."""

    kind: Literal["highway_onramp"] = "highway_onramp"
    upstream_edge: str
    merge_edge: str
    downstream_edge: str
    ramp_edge: str
    accel_lane: str
    join_lanes: tuple[str, ...]  # the mainline lane that ramp vehicles join, on each edge
    merge_junction: str  # the node at the nose; its internal lanes join the mainline too
    mainline_lanes: int
    ramp_angle_deg: float  # [deg] between ramp and mainline
    merge_start_x: float  # [m] start of the acceleration lane (the nose)
    merge_end_x: float  # [m] end of the acceleration lane
    past_merge_x: float  # [m] a vehicle with x beyond this has merged (or failed to)
    mainline_end_x: float  # [m]
    accel_lane_length_m: float  # [m] as built

    def is_ramp_lane(self, lane: str) -> bool:
        """A lane of the ramp edge."""
        return lane.startswith(self.ramp_edge)

    def joins_mainline(self, lane: str) -> bool:
        """The mainline lane that ramp vehicles join (or the junction interior at the nose)."""
        return lane in self.join_lanes or lane.startswith(":" + self.merge_junction)

    def past_nose_mainline(self, lane: str) -> bool:
        """A mainline lane past the nose (the merge edge but its acceleration lane, the downstream edge):
        a ramp vehicle there has merged."""
        edge = lane.rsplit("_", 1)[0]
        return (edge == self.merge_edge and lane != self.accel_lane) or edge == self.downstream_edge


class RuralLandmarks(Landmarks):
    """``rural_two_lane``: one lane per direction; lateral geometry measured on the built network."""

    kind: Literal["rural_two_lane"] = "rural_two_lane"
    east_edge: str
    west_edge: str
    east_lane: str
    west_lane: str
    east_lane_y: float  # [m]
    west_lane_y: float  # [m]
    opposite_lane_offset_m: float  # [m] to the LEFT of an eastbound vehicle (+y)
    length_m: float  # [m] as built


class MeteredRamp(_Frozen):
    """One metered on-ramp of the beltway (direction d, interchange k) and its detectors."""

    onramp_edge: str
    meter_edge: str
    offramp_edge: str
    merge_edge: str
    meter_tls: str
    ramp_length_m: float  # [m]
    ramp_storage_veh: int
    e1_upstream: tuple[str, ...]  # loops per lane upstream of the merge
    e1_downstream: tuple[str, ...]  # downstream
    e2_ramp: str  # lane area over the on-ramp storage
    e1_ramp: str  # loop after the meter
    e1_offramp: str
    e1_upstream_pos_m: float  # [m]
    e1_downstream_pos_m: float  # [m]


class Interchange(_Frozen):
    index: int
    angle_rad: float
    origin_edge: str
    destination_edge: str
    ccw: MeteredRamp
    cw: MeteredRamp

    def ramp(self, direction: str) -> MeteredRamp:
        return self.ccw if direction == "ccw" else self.cw


class RingSegment(_Frozen):
    edge: str
    length_m: float  # [m] edge plus the junction interior after it
    edge_length_m: float  # [m]
    lanes: int
    interchange: int
    role: str  # weave | merge | link
    offramp: str | None
    onramp: str | None


class MeterProgram(_Frozen):
    green_phase: int
    red_phase: int
    green_state: str
    red_state: str
    green_s: float  # [s]
    red_s: float  # [s]
    off_program: str


class BeltwayLandmarks(Landmarks):
    """``beltway``: per-interchange ramps, meters and detectors, and the ring segments for METANET."""

    kind: Literal["beltway"] = "beltway"
    directions: dict[str, str]
    interchanges: tuple[Interchange, ...]
    ring: dict[str, tuple[RingSegment, ...]]
    ring_length_m: dict[str, float]  # [m] per direction
    lanes: int
    meter: MeterProgram
    vehicle_spacing_m: float  # [m] storage per queued vehicle

    def declared_detectors(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        loops: list[str] = []
        areas: list[str] = []
        for ic in self.interchanges:
            for d in ("ccw", "cw"):
                r = ic.ramp(d)
                loops += [*r.e1_upstream, *r.e1_downstream, r.e1_ramp, r.e1_offramp]
                areas.append(r.e2_ramp)
        return tuple(loops), tuple(areas), tuple(ic.origin_edge for ic in self.interchanges)


class StreetParkingLandmarks(Landmarks):
    """``parking_street``: a two-way street with a row of parking bays right of the eastbound lane
    (beyond the kerb line y = ``kerb_y``); bay centres at (``bay_x[k]``, ``bay_y``), ``taken``: a SUMO
    car parks there from the start (cars parked with heading ``parked_heading`` [rad])."""

    kind: Literal["parking_street"] = "parking_street"
    east_edge: str
    west_edge: str
    east_lane: str
    east_lane_y: float  # [m]
    kerb_y: float  # [m]
    layout: str  # parallel | perpendicular
    bay_length_m: float  # [m] along the street
    bay_depth_m: float  # [m] across
    bay_x: tuple[float, ...]  # [m]
    bay_y: float  # [m]
    parked_heading: float  # [rad]
    taken: tuple[bool, ...]
    length_m: float  # [m]
    end_x: float  # [m] a counting line near the street's east end (``traffic_kpis``)


class FlowMergeLandmarks(Landmarks):
    """``flow_merge``: Flow's merge benchmark network (a single-lane highway along +x, a single-lane
    on-ramp joining it at the junction ``merge_junction`` without an acceleration lane); x measured on
    the built network."""

    kind: Literal["flow_merge"] = "flow_merge"
    highway_edges: tuple[str, ...]  # in driving order
    ramp_edges: tuple[str, ...]
    post_merge_edge: str
    merge_junction: str
    mainline_start_x: float  # [m] start of the highway inflow edge
    merge_x: float  # [m] the junction where the ramp joins (end of the highway's pre-merge edge)
    past_merge_x: float  # [m] start of the post-merge edge (past the junction)
    mainline_end_x: float  # [m]
    ramp_angle_deg: float  # [deg] between ramp and highway

    def is_ramp_lane(self, lane: str) -> bool:
        """A lane of one of the ramp's edges."""
        return lane.rsplit("_", 1)[0] in self.ramp_edges


class SumoFilesLandmarks(Landmarks):
    """``sumo_files``: a user's own SUMO network.  corridor knows no merge, ramp or bay on it: only
    what is measured on the network file."""

    kind: Literal["sumo_files"] = "sumo_files"
    edges: int  # normal (non-internal) edges
    lanes: int  # their lanes
    lanes_length_m: float  # [m] summed over those lanes
    bbox_m: tuple[float, float, float, float]  # [m] x min, y min, x max, y max of the network


LANDMARK_MODELS: dict[str, type[Landmarks]] = {
    m.model_fields["kind"].default: m
    for m in (
        OnrampLandmarks, RuralLandmarks, BeltwayLandmarks, StreetParkingLandmarks, FlowMergeLandmarks,
        SumoFilesLandmarks,
    )
}


def parse_landmarks(data: dict[str, Any]) -> Landmarks:
    """The typed landmarks of a cache entry's JSON (by its ``kind``; a kind no model claims, e.g. a
    plug-in builder's, is read as the plain ``Landmarks``)."""
    model = LANDMARK_MODELS.get(data["kind"])
    if model is None:
        return Landmarks.model_validate({k: data[k] for k in Landmarks.model_fields})
    return model.model_validate(data)
