"""Beltway access roads: multi-lane arterials, conflict-free entry/exit hubs and long (winding) ramps."""

from __future__ import annotations

import pytest
import sumolib

from corridor.traffic.networks.registry import build_network


@pytest.fixture(scope="module")
def net(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, sumolib.net.Net]:
    params = {"interchanges": 4, "circumference_m": 8000.0, "lanes": 2, "arterial_lanes": 2,
              "ramp_length_m": 900.0, "ramp_span_m": 200.0}
    built = build_network("beltway", params, tmp_path_factory.mktemp("belt"))
    return built, sumolib.net.readNet(str(built.net_file))


def test_arterials_have_the_requested_lanes_and_exits_merge_without_conflict(net: tuple) -> None:
    _, sn = net
    for k in range(4):
        assert sn.getEdge(f"a{k}_in").getLaneNumber() == 2 and sn.getEdge(f"b{k}_in").getLaneNumber() == 2
        assert sn.getEdge(f"a{k}_out").getLaneNumber() == 3  # off-ramp lane + bridge lanes
        entry, exit_ = sn.getEdge(f"a{k}_in").getToNode(), sn.getEdge(f"a{k}_out").getFromNode()
        assert entry.getID() != exit_.getID()  # entering and leaving traffic never share a junction
        assert sn.getEdge(f"ccw{k}_off").getToNode().getID() == exit_.getID()
        assert sn.getEdge(f"cw{k}_off").getToNode().getID() == sn.getEdge(f"b{k}_out").getFromNode().getID()
        # each stream into a{k}_out has its own lanes: no two incoming lanes feed one outgoing lane
        targets = [c.getToLane().getIndex() for e in exit_.getIncoming() for c in e.getOutgoing()[sn.getEdge(f"a{k}_out")]]
        assert sorted(targets) == [0, 1, 2]


def test_ramp_storage_is_the_full_length_while_the_weave_stays_short(net: tuple) -> None:
    built, sn = net
    ic = built.landmarks.interchanges[0].ccw
    assert sn.getLane("ccw0_on_0").getLength() == pytest.approx(900.0, abs=1.0)
    assert ic.ramp_storage_veh == 120  # 900 m / 7.5 m per queued vehicle
    weave = sn.getEdge("ccw0_weave").getLength()
    assert weave < 150.0 + 200.0 + 120.0 + 30.0  # off-ramp lead + ramp span + connector (+ junctions)


def test_every_route_is_connected(net: tuple) -> None:
    built, sn = net
    for name, edges in built.routes.items():
        for a, b in zip(edges[:-1], edges[1:]):
            assert sn.getEdge(b) in sn.getEdge(a).getOutgoing(), f"{name}: {a} -> {b}"


