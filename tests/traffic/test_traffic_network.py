"""Network registry, params validation, cache and geometry of the built networks (no simulation)."""

from __future__ import annotations

import math
import multiprocessing
import xml.etree.ElementTree as ET
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import sumolib
from pydantic import ValidationError

from corridor.traffic.networks.registry import (
    NetworkBuildError,
    PlainNet,
    build_network,
    builder_names,
    params_model,
    run_netconvert,
)


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("netcache")


def test_registry_has_the_three_builders_with_strict_frozen_models() -> None:
    assert {"highway_onramp", "beltway", "rural_two_lane", "parking_street", "sumo_files"} <= set(builder_names())
    for kind in ("highway_onramp", "beltway", "rural_two_lane"):
        model = params_model(kind)
        assert model.model_config["extra"] == "forbid" and model.model_config["frozen"]
        with pytest.raises(ValidationError, match="not_a_field"):
            model.model_validate({"not_a_field": 1})
    with pytest.raises(KeyError, match="unknown network kind"):
        params_model("no_such_network")


def test_impossible_params_are_rejected_naming_the_field() -> None:
    model = params_model("highway_onramp")
    with pytest.raises(ValidationError, match="accel_lane_length_m"):
        model(accel_lane_length_m=1200.0, downstream_length_m=1000.0)
    with pytest.raises(ValidationError, match="mainline_lanes"):
        model(mainline_lanes=0)
    with pytest.raises(ValidationError, match="circumference_m"):
        params_model("beltway")(circumference_m=2000.0, interchanges=8)


def test_netconvert_failure_is_one_readable_line(tmp_path: Path) -> None:
    plain = PlainNet(
        nodes=[{"id": "a", "x": 0.0, "y": 0.0}],
        edges=[{"id": "e", "from": "a", "to": "missing_node", "numLanes": 1}],
    )
    with pytest.raises(NetworkBuildError) as info:
        run_netconvert(tmp_path, plain)
    message = str(info.value)
    assert "\n" not in message and message.startswith("netconvert failed: Error:")
    assert "missing_node" in message


def test_cache_hit_reuses_files_and_params_change_the_hash(cache: Path) -> None:
    first = build_network("rural_two_lane", {"length_m": 1200.0}, cache)
    stamp = first.net_file.stat().st_mtime_ns
    again = build_network("rural_two_lane", params_model("rural_two_lane")(length_m=1200.0), cache)
    assert again.net_file == first.net_file and again.net_file.stat().st_mtime_ns == stamp
    assert again.params_hash == first.params_hash and again.landmarks == first.landmarks
    other = build_network("rural_two_lane", {"length_m": 1300.0}, cache)
    assert other.params_hash != first.params_hash and other.net_file != first.net_file
    assert not [p for p in cache.iterdir() if p.name.startswith(".")]  # no temp dirs left behind


def _build_in_child(cache: str) -> str:
    return str(build_network("highway_onramp", {"upstream_length_m": 777.0}, Path(cache)).net_file)


def test_concurrent_builds_share_one_cache_entry(tmp_path: Path) -> None:
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=2, mp_context=ctx) as pool:
        paths = list(pool.map(_build_in_child, [str(tmp_path)] * 4))
    assert len(set(paths)) == 1 and Path(paths[0]).exists()
    assert [p.name for p in tmp_path.iterdir()] == [Path(paths[0]).parent.name]  # one entry, no temp dirs
    sumolib.net.readNet(paths[0])  # the published file is complete XML


def test_highway_geometry_and_landmarks(cache: Path) -> None:
    p = {
        "upstream_length_m": 1000.0,
        "downstream_length_m": 800.0,
        "accel_lane_length_m": 250.0,
        "mainline_lanes": 3,
    }
    net = build_network("highway_onramp", p, cache)
    lm = net.landmarks
    assert net.routes == {
        "main": ("upstream", "merge", "downstream"),
        "ramp": ("ramp", "merge", "downstream"),
    }
    # netconvert trims edges at junctions by a few metres only
    assert lm.merge_start_x == pytest.approx(1000.0, abs=8.0)
    assert lm.merge_end_x == pytest.approx(1250.0, abs=8.0)
    assert lm.past_merge_x == lm.merge_end_x and lm.mainline_end_x == pytest.approx(1800.0, abs=0.1)
    sumo_net = sumolib.net.readNet(str(net.net_file))
    assert (
        sumo_net.getEdge("merge").getLaneNumber() == 4 and sumo_net.getEdge("upstream").getLaneNumber() == 3
    )
    assert not sumo_net.getLane("merge_0").getOutgoing()  # the acceleration lane ends
    accel = net.lane_shapes["merge_0"]
    assert accel.shape[1] == 2 and np.allclose(accel[:, 1], -3.5 * 3.5)  # rightmost of 4 lanes below y = 0
    ramp = net.lane_shapes["ramp_0"]
    assert ramp[0, 0] < ramp[-1, 0] and ramp[0, 1] < ramp[-1, 1] < 0  # from below, heading +x


def test_rural_lanes_share_the_centreline(cache: Path) -> None:
    net = build_network("rural_two_lane", {"lane_width_m": 3.25, "length_m": 2000.0}, cache)
    lm = net.landmarks
    # netconvert stores coordinates to the centimetre
    assert lm.opposite_lane_offset_m == pytest.approx(3.25, abs=0.011)
    assert lm.east_lane_y == pytest.approx(-1.625, abs=0.006) and lm.west_lane_y == pytest.approx(
        1.625, abs=0.006
    )
    east, west = net.lane_shapes["east_0"], net.lane_shapes["west_0"]
    assert east[-1, 0] - east[0, 0] == pytest.approx(2000.0) and west[0, 0] > west[-1, 0]


def test_beltway_routes_connected_and_ring_segments_consistent(cache: Path) -> None:
    n_ic = 5
    net = build_network("beltway", {"interchanges": n_ic, "circumference_m": 9000.0, "lanes": 3}, cache)
    sumo_net = sumolib.net.readNet(str(net.net_file))
    assert len(net.routes) == 2 * n_ic * (n_ic - 1)
    assert {"od_0_3_cw", "od_0_3_ccw", "od_4_1_cw"} <= set(net.routes)
    for name, edges in net.routes.items():
        for a, b in zip(edges[:-1], edges[1:]):
            assert sumo_net.getEdge(b) in sumo_net.getEdge(a).getOutgoing(), f"{name}: {a} -> {b}"
    lm = net.landmarks
    for d, sign in (("ccw", 1.0), ("cw", -1.0)):
        ring = lm.ring[d]
        assert len(ring) == 3 * n_ic
        for seg, nxt in zip(ring, ring[1:] + ring[:1]):  # a closed chain in travel order
            assert sumo_net.getEdge(nxt.edge) in sumo_net.getEdge(seg.edge).getOutgoing()
        radius = 9000.0 / (2 * math.pi) + sign * (10.0 / 2 + 3 * 3.5 / 2)  # SUMO measures the lane-set centre
        # segment lengths (edges + junction interiors) add up to the driven ring: the polygon of shape
        # points (50 m chords) is a hair shorter than the circle, junction corners cut a few metres
        assert lm.ring_length_m[d] == pytest.approx(2 * math.pi * radius, rel=0.002)
        assert sum(s.edge_length_m for s in ring) < lm.ring_length_m[d]
        assert [s.lanes for s in ring[:3]] == [3, 4, 3]
        assert [lm.interchanges[s.interchange].index for s in ring[::3]] == (
            list(range(n_ic)) if d == "ccw" else [0, *range(n_ic - 1, 0, -1)]
        )
        # counter-clockwise: the angle of successive edge midpoints increases
        mids = [np.mean(net.lane_shapes[f"{s.edge}_0"], axis=0) for s in ring]
        turns = np.diff(np.unwrap([math.atan2(y, x) for x, y in mids]))
        assert np.all(np.sign(turns) == sign)


def test_beltway_detectors_file_matches_landmarks(cache: Path) -> None:
    net = build_network("beltway", {}, cache)
    (add_file,) = net.additional_files
    root = ET.parse(add_file).getroot()
    loops = {e.get("id"): e.get("lane") for e in root.iter("inductionLoop")}
    areas = {e.get("id"): e for e in root.iter("laneAreaDetector")}
    for ic in net.landmarks.interchanges:
        for d in ("ccw", "cw"):
            facts = ic.ramp(d)
            assert len(facts.e1_upstream) == len(facts.e1_downstream) == 2
            assert all(loops[i].startswith(f"{d}{ic.index}_weave_") for i in facts.e1_upstream)
            assert all(loops[i].startswith(f"{d}{ic.index}_link_") for i in facts.e1_downstream)
            e2 = areas[facts.e2_ramp]
            assert e2.get("lane") == f"{facts.onramp_edge}_0"
            assert float(e2.get("endPos")) - float(e2.get("pos")) == pytest.approx(300.0, abs=0.01)
            assert facts.ramp_storage_veh == 40 and facts.meter_tls == f"meter_{d}{ic.index}"
