"""Builder ``beltway``: a two-carriageway ring freeway with metered diamond interchanges.

Directions (right-hand traffic, as on the Capital Beltway): the OUTER carriageway runs
counter-clockwise (``ccw``, angle increasing) and the INNER carriageway clockwise (``cw``).  With
right-hand traffic the right shoulder of the outer carriageway faces away from the ring centre and that
of the inner carriageway faces the centre, so every ramp leaves and joins on the right (lane 0).

Interchange k sits at angle ``2 pi k / N`` (k = 0 at +x, the ring centre at the origin).  An
origin node ``o{k}`` lies outside the ring; the arterial ``a{k}_in`` (``arterial_lanes`` lanes) leads
to the outer entry hub ``ho{k}`` (outer on-ramp) and on over the bridge ``b{k}_in`` (grade separated:
no shared node with the carriageways) to the inner entry hub ``hi{k}`` (inner on-ramp).  Leaving
traffic uses separate exit hubs: the inner off-ramp ends at ``hix{k}``, the bridge ``b{k}_out`` runs
to the outer exit hub ``hox{k}`` where the outer off-ramp joins, and ``a{k}_out`` (one lane more, so
the two streams keep their own lanes) leads to the destination node ``ox{k}``.  No junction has
crossing streams, so the arterials never throttle the ramps.  Per direction d and interchange k, in
the direction of travel::

    ... {d}{k-1}_link -> D --{d}{k}_weave--> M --{d}{k}_merge--> E --{d}{k}_link--> D' ...
                         |                   ^   (lanes + acceleration lane 0)
              {d}{k}_off v                   | {d}{k}_meter  (short, after the signal)
                   exit hub   entry hub --{d}{k}_on--> [meter TLS "meter_{d}{k}"]

``{d}{k}_on`` is the ramp storage (``ramp_length_m``, drawn over ``ramp_span_m`` along the ring; covered
by lane-area detector ``e2_ramp_{d}{k}``).
The meter is a one-link traffic light whose program ``0`` has phase 0 = green ("G") and
phase 1 = red ("r"); a controller drives it with ``trafficlight.setRedYellowGreenState`` or phase
durations, and ``trafficlight.setProgram(tls, "off")`` removes metering (unmetered baseline).

Routes: ``od_{i}_{j}_{d}`` for every origin interchange i, destination j != i and direction
d in {"cw", "ccw"}: from ``a{i}_in`` onto the d carriageway at i, off at j, out by ``a{j}_out``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import sumolib
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.traffic.networks.landmarks import BeltwayLandmarks
from corridor.traffic.networks.registry import (
    BuildOutput,
    PlainNet,
    element,
    register_builder,
    run_netconvert,
    write_xml,
)

DIRECTIONS = ("ccw", "cw")  # outer, inner
OFFRAMP_LEAD_M = 150.0  # [m] diverge point before the interchange centre
RAMP_OFFSET_M = 40.0  # [m] lateral distance of the ramp/hub from the carriageway reference line
CONNECTOR_M = 120.0  # [m] along-road length of the meter-to-merge connector
MIN_LINK_M = 200.0  # [m] shortest ring link between two interchanges
VEHICLE_SPACING_M = 7.5  # [m] storage per queued vehicle
ARC_STEP_M = 50.0  # [m] shape point spacing along arcs
EXIT_HUB_OFFSET_M = 30.0  # [m] exit hub before the entry hub along the ramp circle


class BeltwayParams(BaseModel):
    """Ring size, number of interchanges, lanes, speeds, ramp geometry and the default meter program."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    circumference_m: float = Field(12000.0, gt=0)  # [m] of the ring reference circle
    interchanges: int = Field(4, ge=2, le=32)
    lanes: int = Field(2, ge=1, le=6)
    mainline_speed_mps: float = Field(27.8, gt=0)  # [m/s]
    ramp_speed_mps: float = Field(16.67, gt=0)  # [m/s]
    arterial_speed_mps: float = Field(13.89, gt=0)  # [m/s]
    ramp_length_m: float = Field(300.0, ge=30)  # [m] on-ramp storage up to the meter
    # [m] along-ring extent of the on-ramp; None = ramp_length_m.  A shorter span models a winding
    # (or looped) ramp: SUMO drives the full ramp_length_m (edge length attribute) while the weaving
    # section between off-ramp and merge stays short.
    ramp_span_m: float | None = Field(None, ge=30)
    accel_lane_length_m: float = Field(150.0, gt=0)  # [m]
    arterial_length_m: float = Field(300.0, ge=30)  # [m] origin node to outer hub
    arterial_lanes: int = Field(1, ge=1, le=4)  # lanes of arterials and bridges (one lane: ~1800 veh/h)
    lane_width_m: float = Field(3.5, gt=2.0)  # [m]
    median_m: float = Field(10.0, ge=0)  # [m] between the two carriageway reference lines
    meter_green_s: float = Field(2.0, gt=0)  # [s] default program: one vehicle per green
    meter_red_s: float = Field(2.0, gt=0)  # [s]
    detector_period_s: float = Field(60.0, gt=0)  # [s] aggregation period of detector output

    @model_validator(mode="after")
    def _interchanges_fit(self) -> BeltwayParams:
        for d in DIRECTIONS:
            g = _geometry(self, d)
            used = g["off_lead"] + g["ramp"] + g["connector"] + g["accel"] + MIN_LINK_M / g["radius"]
            if not used <= 2 * math.pi / self.interchanges:  # NaN (collapsed inner ring) fails too
                raise ValueError(
                    f"circumference_m ({self.circumference_m:g} m) is too small for {self.interchanges} "
                    f"interchanges with ramp_length_m={self.ramp_length_m:g} m and "
                    f"accel_lane_length_m={self.accel_lane_length_m:g} m"
                )
        return self


def _geometry(p: BeltwayParams, d: str) -> dict[str, float]:
    """Reference radius [m], travel sign, ramp side and the angular spans [rad] of one carriageway."""
    r_ref = p.circumference_m / (2 * math.pi)
    sign, side = (1.0, 1.0) if d == "ccw" else (-1.0, -1.0)  # travel direction; +1 = ramps outside
    radius = r_ref + side * p.median_m / 2
    ramp_radius = radius + side * RAMP_OFFSET_M
    if ramp_radius <= RAMP_OFFSET_M:
        ramp_radius = float("nan")  # the inner ring collapsed: every span below becomes NaN
    return {
        "radius": radius,
        "sign": sign,
        "side": side,
        "ramp_radius": ramp_radius,
        "off_lead": OFFRAMP_LEAD_M / radius,
        "ramp": (p.ramp_span_m or p.ramp_length_m) / ramp_radius,
        "connector": CONNECTOR_M / radius,
        "accel": p.accel_lane_length_m / radius,
    }


def _xy(theta: float, radius: float) -> tuple[float, float]:
    return (radius * math.cos(theta), radius * math.sin(theta))


def _arc(theta_a: float, theta_b: float, radius: float) -> list[tuple[float, float]]:
    """Polyline along a circle from theta_a to theta_b (either direction), endpoints included."""
    n = max(2, int(math.ceil(abs(theta_b - theta_a) * radius / ARC_STEP_M)) + 1)
    return [_xy(t, radius) for t in np.linspace(theta_a, theta_b, n)]


def _next(k: int, d: str, n: int) -> int:
    """Index of the interchange after k in the direction of travel."""
    return (k + 1) % n if d == "ccw" else (k - 1) % n


def _angles(p: BeltwayParams, d: str, k: int) -> dict[str, float]:
    """Angles [rad] of hub, diverge (D), meter (Q), merge (M) and accel-end (E) of interchange k."""
    g = _geometry(p, d)
    hub = 2 * math.pi * k / p.interchanges
    q = hub + g["sign"] * g["ramp"]
    m = q + g["sign"] * g["connector"]
    return {"hub": hub, "D": hub - g["sign"] * g["off_lead"], "Q": q, "M": m, "E": m + g["sign"] * g["accel"]}


def _unwrap(start: float, end: float, sign: float) -> float:
    """``end`` shifted by whole turns so that it lies ahead of ``start`` in the travel direction."""
    while sign * (end - start) <= 0:
        end += sign * 2 * math.pi
    while sign * (end - start) > 2 * math.pi:
        end -= sign * 2 * math.pi
    return end


def _carriageway(p: BeltwayParams, d: str, plain: PlainNet) -> None:
    """Nodes, edges and connections of one carriageway with all its ramps."""
    g, n, w = _geometry(p, d), p.lanes, p.lane_width_m
    r, rr, side = g["radius"], g["ramp_radius"], g["side"]
    main = {"priority": 10, "speed": p.mainline_speed_mps, "width": w, "spreadType": "right"}
    ramp = {"priority": 5, "speed": p.ramp_speed_mps, "width": w, "spreadType": "center", "numLanes": 1}
    hub = "ho" if d == "ccw" else "hi"
    for k in range(p.interchanges):
        a, a_next = _angles(p, d, k), _angles(p, d, _next(k, d, p.interchanges))
        e_end = _unwrap(a["E"], a_next["D"], g["sign"])
        x = f"{d}{k}"
        plain.nodes += [
            {"id": f"D_{x}", "x": _xy(a["D"], r)[0], "y": _xy(a["D"], r)[1], "type": "priority"},
            {"id": f"M_{x}", "x": _xy(a["M"], r)[0], "y": _xy(a["M"], r)[1], "type": "priority"},
            {"id": f"E_{x}", "x": _xy(a["E"], r)[0], "y": _xy(a["E"], r)[1], "type": "priority"},
            {
                "id": f"Q_{x}",
                "x": _xy(a["Q"], rr)[0],
                "y": _xy(a["Q"], rr)[1],
                "type": "traffic_light",
                "tl": f"meter_{x}",
                "tlType": "static",
            },
        ]
        nxt = f"D_{d}{_next(k, d, p.interchanges)}"
        accel_r = r + side * (n + 0.5) * w  # centre of the acceleration lane / right of lane 0
        plain.edges += [
            {
                "id": f"{x}_weave",
                "from": f"D_{x}",
                "to": f"M_{x}",
                "numLanes": n,
                "shape": _arc(a["D"], a["M"], r),
                **main,
            },
            {
                "id": f"{x}_merge",
                "from": f"M_{x}",
                "to": f"E_{x}",
                "numLanes": n + 1,
                "shape": _arc(a["M"], a["E"], r),
                **main,
            },
            {
                "id": f"{x}_link",
                "from": f"E_{x}",
                "to": nxt,
                "numLanes": n,
                "shape": _arc(a["E"], e_end, r),
                **main,
            },
            {
                "id": f"{x}_off",
                "from": f"D_{x}",
                "to": f"{hub}x{k}",
                "shape": [_xy(a["D"], accel_r), _exit_hub_xy(p, d, k)],
                **ramp,
            },
            {
                "id": f"{x}_on",
                "from": f"{hub}{k}",
                "to": f"Q_{x}",
                "shape": _arc(a["hub"], a["Q"], rr),
                "length": p.ramp_length_m,
                **ramp,
            },
            {
                "id": f"{x}_meter",
                "from": f"Q_{x}",
                "to": f"M_{x}",
                "shape": [_xy(a["Q"], rr), _xy(a["M"], accel_r)],
                **ramp,
            },
        ]
        prev = f"{d}{_prev(k, d, p.interchanges)}_link"
        plain.connections += [
            *({"from": prev, "to": f"{x}_weave", "fromLane": i, "toLane": i} for i in range(n)),
            {"from": prev, "to": f"{x}_off", "fromLane": 0, "toLane": 0},
            *({"from": f"{x}_weave", "to": f"{x}_merge", "fromLane": i, "toLane": i + 1} for i in range(n)),
            {"from": f"{x}_meter", "to": f"{x}_merge", "fromLane": 0, "toLane": 0},
            *({"from": f"{x}_merge", "to": f"{x}_link", "fromLane": i + 1, "toLane": i} for i in range(n)),
        ]
        plain.tl_logics.append(
            (
                {"id": f"meter_{x}", "type": "static", "programID": "0", "offset": 0},
                [{"duration": p.meter_green_s, "state": "G"}, {"duration": p.meter_red_s, "state": "r"}],
            )
        )


def _prev(k: int, d: str, n: int) -> int:
    """Index of the interchange before k in the direction of travel."""
    return (k - 1) % n if d == "ccw" else (k + 1) % n


def _exit_hub_xy(p: BeltwayParams, d: str, k: int) -> tuple[float, float]:
    """Position [m] of the exit hub of carriageway d at interchange k (off-ramp end).

    It sits ``EXIT_HUB_OFFSET_M`` before the entry hub in the travel direction, so leaving and
    entering traffic never share a junction (no crossing conflicts that would throttle the ramps).
    """
    g = _geometry(p, d)
    theta = 2 * math.pi * k / p.interchanges - g["sign"] * EXIT_HUB_OFFSET_M / g["ramp_radius"]
    return _xy(theta, g["ramp_radius"])


def _arterials(p: BeltwayParams, plain: PlainNet) -> None:
    """Origin/destination nodes, entry and exit hubs, two-way arterials and bridges.

    Entering traffic: ``a{k}_in`` (origin o{k} -> outer entry hub ho{k}, a pure diverge to the outer
    on-ramp and the bridge ``b{k}_in`` to the inner entry hub hi{k}).  Leaving traffic: off-ramps end
    at exit hubs hox{k} / hix{k}; ``b{k}_out`` runs hix{k} -> hox{k}, and ``a{k}_out`` (one lane more
    than the arterial, so the outer off-ramp merges without conflict) runs hox{k} -> destination ox{k}.
    """
    r_out = _geometry(p, "ccw")["ramp_radius"]
    r_in = _geometry(p, "cw")["ramp_radius"]
    n = p.arterial_lanes
    road = {"speed": p.arterial_speed_mps, "width": p.lane_width_m, "spreadType": "right", "priority": 3}
    for k in range(p.interchanges):
        theta = 2 * math.pi * k / p.interchanges
        dest = _xy(theta - EXIT_HUB_OFFSET_M / (r_out + p.arterial_length_m), r_out + p.arterial_length_m)
        nodes = {
            f"o{k}": _xy(theta, r_out + p.arterial_length_m),
            f"ox{k}": dest,
            f"ho{k}": _xy(theta, r_out),
            f"hi{k}": _xy(theta, r_in),
            f"hox{k}": _exit_hub_xy(p, "ccw", k),
            f"hix{k}": _exit_hub_xy(p, "cw", k),
        }
        plain.nodes += [{"id": i, "x": xy[0], "y": xy[1], "type": "priority"} for i, xy in nodes.items()]
        plain.edges += [
            {"id": f"a{k}_in", "from": f"o{k}", "to": f"ho{k}", "numLanes": n, **road},
            {"id": f"a{k}_out", "from": f"hox{k}", "to": f"ox{k}", "numLanes": n + 1, **road},
            {"id": f"b{k}_in", "from": f"ho{k}", "to": f"hi{k}", "numLanes": n, **road},
            {"id": f"b{k}_out", "from": f"hix{k}", "to": f"hox{k}", "numLanes": n, **road},
        ]
        plain.connections += [
            {"from": f"ccw{k}_off", "to": f"a{k}_out", "fromLane": 0, "toLane": 0},
            *({"from": f"b{k}_out", "to": f"a{k}_out", "fromLane": i, "toLane": i + 1} for i in range(n)),
        ]


def _plain(p: BeltwayParams) -> PlainNet:
    plain = PlainNet()
    _arterials(p, plain)
    for d in DIRECTIONS:
        _carriageway(p, d, plain)
    return plain


def _routes(p: BeltwayParams) -> dict[str, tuple[str, ...]]:
    """``od_{i}_{j}_{d}``: origin arterial -> on-ramp -> ring -> off-ramp -> destination arterial."""
    routes: dict[str, tuple[str, ...]] = {}
    n = p.interchanges
    for d in DIRECTIONS:
        for i in range(n):
            for j in range(n):
                if i == j:
                    continue
                enter = (f"a{i}_in",) if d == "ccw" else (f"a{i}_in", f"b{i}_in")
                leave = (f"a{j}_out",) if d == "ccw" else (f"b{j}_out", f"a{j}_out")
                ring = [f"{d}{i}_on", f"{d}{i}_meter", f"{d}{i}_merge", f"{d}{i}_link"]
                k = _next(i, d, n)
                while k != j:
                    ring += [f"{d}{k}_weave", f"{d}{k}_merge", f"{d}{k}_link"]
                    k = _next(k, d, n)
                routes[f"od_{i}_{j}_{d}"] = (*enter, *ring, f"{d}{j}_off", *leave)
    return routes


def _detector_elements(p: BeltwayParams, net: sumolib.net.Net) -> tuple[list[str], dict[str, dict[str, Any]]]:
    """E1 loops up/downstream of every merge, at every meter and off-ramp; E2 over every on-ramp."""
    elements: list[str] = []
    ids: dict[str, dict[str, Any]] = {}
    common = {"period": p.detector_period_s, "file": "NUL"}
    for d in DIRECTIONS:
        for k in range(p.interchanges):
            x = f"{d}{k}"
            weave, link = net.getEdge(f"{x}_weave"), net.getEdge(f"{x}_link")
            up_pos = max(weave.getLength() - 30.0, 1.0)
            down_pos = min(100.0, link.getLength() / 2)
            up = [f"e1_up_{x}_{i}" for i in range(p.lanes)]
            down = [f"e1_down_{x}_{i}" for i in range(p.lanes)]
            for i in range(p.lanes):
                elements.append(
                    element("inductionLoop", {"id": up[i], "lane": f"{x}_weave_{i}", "pos": up_pos, **common})
                )
                elements.append(
                    element(
                        "inductionLoop", {"id": down[i], "lane": f"{x}_link_{i}", "pos": down_pos, **common}
                    )
                )
            on_len = net.getLane(f"{x}_on_0").getLength()
            meter_pos = min(5.0, net.getLane(f"{x}_meter_0").getLength() / 2)
            off_pos = net.getLane(f"{x}_off_0").getLength() / 2
            elements += [
                element(
                    "laneAreaDetector",
                    {"id": f"e2_ramp_{x}", "lane": f"{x}_on_0", "pos": 0.0, "endPos": on_len, **common},
                ),
                element(
                    "inductionLoop",
                    {"id": f"e1_ramp_{x}", "lane": f"{x}_meter_0", "pos": meter_pos, **common},
                ),
                element(
                    "inductionLoop", {"id": f"e1_off_{x}", "lane": f"{x}_off_0", "pos": off_pos, **common}
                ),
            ]
            ids[x] = {
                "e1_upstream": up,
                "e1_downstream": down,
                "e2_ramp": f"e2_ramp_{x}",
                "e1_ramp": f"e1_ramp_{x}",
                "e1_offramp": f"e1_off_{x}",
                "e1_upstream_pos_m": up_pos,
                "e1_downstream_pos_m": down_pos,
            }
    return elements, ids


def _ring_segments(p: BeltwayParams, net: sumolib.net.Net, d: str) -> list[dict[str, Any]]:
    """Mainline edges of one carriageway in travel order from interchange 0, with lengths [m].

    ``length_m`` is the edge plus the junction interior that follows it, so the segment lengths add up
    to the distance driven around the ring (what a METANET model needs); ``edge_length_m`` is the edge.
    """
    ids: list[tuple[str, int, str]] = []
    k = 0
    for _ in range(p.interchanges):
        ids += [(f"{d}{k}_{role}", k, role) for role in ("weave", "merge", "link")]
        k = _next(k, d, p.interchanges)
    segments: list[dict[str, Any]] = []
    for idx, (edge_id, k, role) in enumerate(ids):
        edge, nxt = net.getEdge(edge_id), net.getEdge(ids[(idx + 1) % len(ids)][0])
        segments.append(
            {
                "edge": edge_id,
                "length_m": float(edge.getLength()) + _junction_length(net, edge, nxt),
                "edge_length_m": float(edge.getLength()),
                "lanes": edge.getLaneNumber(),
                "interchange": k,
                "role": role,
                "offramp": f"{d}{k}_off" if role == "weave" else None,
                "onramp": f"{d}{k}_meter" if role == "merge" else None,
            }
        )
    return segments


def _junction_length(net: sumolib.net.Net, edge: sumolib.net.edge.Edge, nxt: sumolib.net.edge.Edge) -> float:
    """Length [m] of the internal lane(s) from ``edge`` to ``nxt`` (0 without internal links)."""
    conns = edge.getConnections(nxt)
    if not conns or not conns[0].getViaLaneID():
        return 0.0
    total, lane_id = 0.0, conns[0].getViaLaneID()
    while lane_id.startswith(":"):  # a junction interior may be split into several internal lanes
        lane = net.getLane(lane_id)
        total += lane.getLength()
        outgoing = lane.getOutgoing()
        lane_id = outgoing[0].getViaLaneID() or outgoing[0].getToLane().getID() if outgoing else ""
    return float(total)


def _landmarks(
    p: BeltwayParams, net: sumolib.net.Net, detectors: dict[str, dict[str, Any]]
) -> BeltwayLandmarks:
    """Per-interchange ramps, meters and detectors, and the ring segments for METANET."""
    storage = int(p.ramp_length_m // VEHICLE_SPACING_M)
    interchanges = []
    for k in range(p.interchanges):
        entry: dict[str, Any] = {
            "index": k,
            "angle_rad": 2 * math.pi * k / p.interchanges,
            "origin_edge": f"a{k}_in",
            "destination_edge": f"a{k}_out",
        }
        for d in DIRECTIONS:
            x = f"{d}{k}"
            entry[d] = {
                "onramp_edge": f"{x}_on",
                "meter_edge": f"{x}_meter",
                "offramp_edge": f"{x}_off",
                "merge_edge": f"{x}_merge",
                "meter_tls": f"meter_{x}",
                "ramp_length_m": p.ramp_length_m,
                "ramp_storage_veh": storage,
                **detectors[x],
            }
        interchanges.append(entry)
    ring = {d: _ring_segments(p, net, d) for d in DIRECTIONS}
    return BeltwayLandmarks.model_validate({
        "lane_width_m": p.lane_width_m,
        "directions": {"ccw": "outer carriageway, counter-clockwise", "cw": "inner carriageway, clockwise"},
        "interchanges": interchanges,
        "ring": ring,
        "ring_length_m": {d: sum(s["length_m"] for s in ring[d]) for d in DIRECTIONS},
        "lanes": p.lanes,
        "meter": {
            "green_phase": 0,
            "red_phase": 1,
            "green_state": "G",
            "red_state": "r",
            "green_s": p.meter_green_s,
            "red_s": p.meter_red_s,
            "off_program": "off",
        },
        "vehicle_spacing_m": VEHICLE_SPACING_M,
    })


@register_builder("beltway", BeltwayParams, BeltwayLandmarks)
def build_beltway(params: BeltwayParams, work_dir: Path) -> BuildOutput:
    """Build the ring, its detectors file and routes into ``work_dir``."""
    net_file = run_netconvert(work_dir, _plain(params))
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    elements, detector_ids = _detector_elements(params, net)
    add = write_xml(work_dir / "detectors.add.xml", "additional", elements)
    return BuildOutput(
        additional_files=(add.name,), routes=_routes(params), landmarks=_landmarks(params, net, detector_ids)
    )


def carriageway_arcs(p: BeltwayParams, d: str) -> tuple[float, float, list[float]]:
    """(reference radius [m], travel sign (+1 ccw), merge angle [rad] of every interchange) of the
    ``d`` carriageway: the ring link k runs from merge k to the next merge in the travel direction,
    as the METANET model's links do (its segment boundaries; ``corridor.traffic.networks.segments``)."""
    g = _geometry(p, d)
    return float(g["radius"]), float(g["sign"]), [_angles(p, d, k)["M"] for k in range(p.interchanges)]
