"""The built networks drive in SUMO (libsumo, each check in a fresh spawned process)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from corridor.traffic.networks.registry import BuiltNetwork, build_network
from corridor.traffic.sumo.demand import FlowDef, VehicleTypeDef, write_routes

CAR = VehicleTypeDef("car", {"accel": 2.6, "decel": 4.5, "sigma": 0.5, "length": 5.0, "minGap": 2.5})
SUMO_OPTS = [
    "--no-step-log",
    "--no-warnings",
    "--seed",
    "1",
    "--step-length",
    "0.1",
    "--collision.action",
    "warn",
]


def _in_spawn(fn, *args):  # type: ignore[no-untyped-def]
    """libsumo allows one simulation per process: run each check in a fresh one."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(fn, *args).result()


def _start(net: BuiltNetwork, routes: Path) -> Any:
    import libsumo

    add = ["-a", ",".join(map(str, net.additional_files))] if net.additional_files else []
    libsumo.start(["sumo", "-n", str(net.net_file), "-r", str(routes), *add, *SUMO_OPTS])
    return libsumo


def _highway_merge(cache: str, work: str) -> dict[str, Any]:
    net = build_network("highway_onramp", {}, Path(cache))
    flows = [FlowDef("m", "main", "car", [(0.0, 2400.0)]), FlowDef("r", "ramp", "car", [(0.0, 500.0)])]
    routes = write_routes(Path(work) / "h.rou.xml", net.routes, [CAR], flows, end_s=300.0)
    end_x = net.landmarks.merge_end_x
    traci = _start(net, routes)
    ramp, arrived, merged, beyond, teleports, collisions = set(), set(), set(), set(), 0, 0
    try:
        while traci.simulation.getTime() < 420.0:
            traci.simulationStep()
            ramp.update(v for v in traci.simulation.getDepartedIDList() if v.startswith("r."))
            arrived.update(traci.simulation.getArrivedIDList())
            teleports += traci.simulation.getStartingTeleportNumber()
            collisions += traci.simulation.getCollidingVehiclesNumber()
            for v in traci.edge.getLastStepVehicleIDs("downstream"):
                merged.add(v)
            for v in traci.lane.getLastStepVehicleIDs("merge_0"):
                if traci.vehicle.getPosition(v)[0] > end_x + 0.5:
                    beyond.add(v)
    finally:
        traci.close()
    return {"ramp": ramp, "arrived": arrived, "downstream": merged, "beyond": beyond,
            "teleports": teleports, "collisions": collisions}  # fmt: skip


def test_highway_ramp_vehicles_merge_and_leave_downstream(tmp_path: Path) -> None:
    out = _in_spawn(_highway_merge, str(tmp_path), str(tmp_path))
    assert len(out["ramp"]) >= 20  # 500 veh/h for 300 s: ~42 expected
    assert out["ramp"] <= out["downstream"] and out["ramp"] <= out["arrived"]
    assert out["teleports"] == 0 and out["collisions"] == 0
    assert not out["beyond"]  # nobody drives past the end of the acceleration lane


def _beltway_trips(cache: str, work: str) -> dict[str, Any]:
    net = build_network("beltway", {}, Path(cache))
    routes = write_routes(Path(work) / "b.rou.xml", net.routes, [CAR], [], end_s=1.0)
    lm = net.landmarks
    traci = _start(net, routes)
    try:
        out: dict[str, Any] = {"loops": set(traci.inductionloop.getIDList()),
                               "areas": set(traci.lanearea.getIDList()), "tls": set(traci.trafficlight.getIDList())}  # fmt: skip
        traci.trafficlight.setRedYellowGreenState("meter_ccw0", lm.meter.red_state)
        for i, name in enumerate(net.routes):
            traci.vehicle.add(f"v:{name}", name, typeID="car", depart=str(2.0 * i))
        seen_at_meter, arrived, teleports = set(), set(), 0
        while traci.simulation.getTime() < 150.0:  # the red meter holds the od_0_*_ccw vehicles
            traci.simulationStep()
            seen_at_meter.update(traci.inductionloop.getLastStepVehicleIDs("e1_ramp_ccw0"))
        out["queued_on_red"] = traci.lanearea.getLastStepVehicleNumber("e2_ramp_ccw0")
        out["halting_on_red"] = traci.lanearea.getLastStepHaltingNumber("e2_ramp_ccw0")
        out["passed_on_red"] = set(seen_at_meter)
        traci.trafficlight.setProgram("meter_ccw0", lm.meter.off_program)
        while traci.simulation.getMinExpectedNumber() > 0 and traci.simulation.getTime() < 1500.0:
            traci.simulationStep()
            seen_at_meter.update(traci.inductionloop.getLastStepVehicleIDs("e1_ramp_ccw0"))
            arrived.update(traci.simulation.getArrivedIDList())
            teleports += traci.simulation.getStartingTeleportNumber()
        out.update(arrived=arrived, teleports=teleports, seen_at_meter=seen_at_meter)
    finally:
        traci.close()
    return out


def test_beltway_every_od_route_is_driven_and_detectors_and_meters_work(tmp_path: Path) -> None:
    net = build_network("beltway", {}, tmp_path)
    out = _in_spawn(_beltway_trips, str(tmp_path), str(tmp_path))
    assert out["arrived"] == {f"v:{name}" for name in net.routes}  # both directions, every OD pair
    assert out["teleports"] == 0
    ics = net.landmarks.interchanges
    loops = {i for ic in ics for d in ("ccw", "cw") for i in ic.ramp(d).e1_upstream + ic.ramp(d).e1_downstream}
    assert loops <= out["loops"] and len(out["loops"]) == len(loops) + 4 * len(ics)
    assert out["areas"] == {ic.ramp(d).e2_ramp for ic in ics for d in ("ccw", "cw")}
    assert out["tls"] == {ic.ramp(d).meter_tls for ic in ics for d in ("ccw", "cw")}
    from_0_ccw = {f"v:od_0_{j}_ccw" for j in range(1, len(ics))}
    assert out["passed_on_red"] == set() and out["queued_on_red"] == out["halting_on_red"] == len(from_0_ccw)
    assert out["seen_at_meter"] == from_0_ccw  # after switching the meter off, exactly they passed it


def _rural_flows(cache: str, work: str) -> dict[str, Any]:
    net = build_network("rural_two_lane", {}, Path(cache))
    flows = [FlowDef("e", "east", "car", [(0.0, 600.0)]), FlowDef("w", "west", "car", [(0.0, 400.0)])]
    routes = write_routes(Path(work) / "r.rou.xml", net.routes, [CAR], flows, end_s=200.0)
    traci = _start(net, routes)
    ys: dict[str, list[float]] = {"e": [], "w": []}
    arrived: list[str] = []
    try:
        while traci.simulation.getTime() < 360.0:
            traci.simulationStep()
            arrived += traci.simulation.getArrivedIDList()
            for v in traci.vehicle.getIDList():
                ys[v[0]].append(traci.vehicle.getPosition(v)[1])
        collisions = traci.simulation.getCollidingVehiclesNumber()
    finally:
        traci.close()
    return {"arrived": arrived, "ys": ys, "collisions": collisions}


def test_rural_flows_run_in_both_directions_on_their_lanes(tmp_path: Path) -> None:
    net = build_network("rural_two_lane", {}, tmp_path)
    out = _in_spawn(_rural_flows, str(tmp_path), str(tmp_path))
    east = [v for v in out["arrived"] if v.startswith("e.")]
    west = [v for v in out["arrived"] if v.startswith("w.")]
    assert len(east) >= 15 and len(west) >= 8  # 600 and 400 veh/h for 200 s: ~33 and ~22
    assert max(out["ys"]["e"]) == pytest.approx(net.landmarks.east_lane_y, abs=0.01)
    assert min(out["ys"]["w"]) == pytest.approx(net.landmarks.west_lane_y, abs=0.01)
    assert out["collisions"] == 0
