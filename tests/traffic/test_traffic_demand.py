"""Route-file writer: exact step means, file structure, and SUMO's insertions against the profile."""

from __future__ import annotations

import math
import multiprocessing
import xml.etree.ElementTree as ET
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from corridor.traffic.networks.registry import build_network
from corridor.traffic.sumo.demand import FlowDef, VehicleTypeDef, expected_count, mean_rate_vph, write_routes

CAR = VehicleTypeDef("car", {"accel": 2.6, "decel": 4.5, "sigma": 0.5, "length": 5.0, "minGap": 2.5})


def test_mean_rate_is_the_exact_integral_of_the_piecewise_linear_profile() -> None:
    ramp = [(0.0, 0.0), (100.0, 3600.0)]
    assert mean_rate_vph(ramp, 0.0, 100.0) == pytest.approx(1800.0)
    assert mean_rate_vph(ramp, 50.0, 150.0) == pytest.approx((0.5 * (1800 + 3600) * 50 + 3600 * 50) / 100)
    triangle = [(0.0, 0.0), (30.0, 600.0), (60.0, 0.0)]
    assert expected_count(triangle, 0.0, 60.0) == pytest.approx(0.5 * 60 * 600 / 3600)
    assert expected_count(triangle, -60.0, 0.0) == 0.0  # held at the first value before the profile
    step = [(0.0, 0.0), (120.0, 0.0), (120.0, 720.0)]  # a repeated time is a jump
    assert mean_rate_vph(step, 60.0, 120.0) == 0.0 and mean_rate_vph(step, 120.0, 180.0) == 720.0
    assert mean_rate_vph(step, 90.0, 150.0) == pytest.approx(360.0)
    with pytest.raises(ValueError, match="non-decreasing"):
        mean_rate_vph([(10.0, 1.0), (0.0, 1.0)], 0.0, 1.0)


def test_written_flows_are_sorted_stepwise_and_skip_zero_rates(tmp_path: Path) -> None:
    flows = [
        FlowDef("late", "r", "car", [(0.0, 0.0), (120.0, 0.0), (120.0, 720.0)], arrivals="uniform"),
        FlowDef("ramp", "r", "car", [(0.0, 0.0), (180.0, 1800.0)]),
    ]
    path = write_routes(tmp_path / "x.rou.xml", {"r": ["e1", "e2"]}, [CAR], flows, end_s=240.0, step_s=60.0)
    root = ET.parse(path).getroot()
    assert [e.get("id") for e in root.iter("vType")] == ["car"]
    assert root.find("route").get("edges") == "e1 e2"
    got = [(f.get("id"), float(f.get("begin")), f.get("period"), f.get("number")) for f in root.iter("flow")]
    begins = [b for _, b, _, _ in got]
    assert begins == sorted(begins)
    assert [i for i, *_ in got if i.startswith("late")] == ["late.2", "late.3"]  # zero steps skipped
    ramp = {i: p for i, _, p, _ in got if i.startswith("ramp")}
    # step means of the ramp: 300, 900, 1500, 1800 veh/h -> exp(rate per second)
    for k, vph in enumerate([300.0, 900.0, 1500.0, 1800.0]):
        assert ramp[f"ramp.{k}"].startswith("exp(")
        assert float(ramp[f"ramp.{k}"][4:-1]) == pytest.approx(vph / 3600.0)
    assert {v for i, _, _, v in got if i.startswith("late")} == {"12"}  # 720 veh/h for 60 s


def test_unknown_route_or_vtype_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown route"):
        write_routes(tmp_path / "a.xml", {"r": ["e"]}, [CAR], [FlowDef("f", "nope", "car", [(0, 1)])], 10.0)
    with pytest.raises(ValueError, match="unknown vtype"):
        write_routes(tmp_path / "a.xml", {"r": ["e"]}, [CAR], [FlowDef("f", "r", "truck", [(0, 1)])], 10.0)


def _insertions_per_window(cache: str, work: str, profile: list[tuple[float, float]], end_s: float, window_s: float,
                           arrivals: str) -> list[int]:  # fmt: skip
    """Run SUMO on the rural road with one flow; departures counted per window."""
    import libsumo

    net = build_network("rural_two_lane", {"length_m": 500.0}, Path(cache))
    flow = FlowDef("f", "east", "car", profile, arrivals=arrivals)  # type: ignore[arg-type]
    routes = write_routes(Path(work) / "d.rou.xml", net.routes, [CAR], [flow], end_s=end_s)
    libsumo.start(["sumo", "-n", str(net.net_file), "-r", str(routes), "--no-step-log", "--no-warnings",
                   "--seed", "1", "--step-length", "0.5", "--collision.action", "warn"])  # fmt: skip
    counts = [0] * int(math.ceil(end_s / window_s))
    try:
        while libsumo.simulation.getTime() < end_s:
            libsumo.simulationStep()
            window = min(int((libsumo.simulation.getTime() - 1e-6) // window_s), len(counts) - 1)
            counts[window] += libsumo.simulation.getDepartedNumber()
        assert not libsumo.simulation.getPendingVehicles()  # demand was never blocked
    finally:
        libsumo.close()
    return counts


def _in_spawn(fn, *args):  # type: ignore[no-untyped-def]
    """libsumo allows one simulation per process: run each check in a fresh one."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(fn, *args).result()


def test_sumo_poisson_insertions_match_the_profile_integral(tmp_path: Path) -> None:
    # linear ramp 0 -> 1200 veh/h over 2 h: 600 + 1800 expected vehicles per hour-half, Poisson
    profile = [(0.0, 0.0), (7200.0, 1200.0)]
    counts = _in_spawn(
        _insertions_per_window, str(tmp_path), str(tmp_path), profile, 7200.0, 3600.0, "poisson"
    )
    expected = [expected_count(profile, 0.0, 3600.0), expected_count(profile, 3600.0, 7200.0)]
    assert expected == pytest.approx([300.0, 900.0])
    for got, mean in zip(counts, expected):
        assert abs(got - mean) <= 4 * math.sqrt(mean), (counts, expected)
    # the ramp-up is visible: the second hour exceeds the first by far more than the noise
    assert counts[1] - counts[0] > 4 * math.sqrt(sum(expected))


def test_sumo_uniform_insertions_follow_the_step_means(tmp_path: Path) -> None:
    profile = [(0.0, 360.0), (1800.0, 360.0), (1800.0, 1080.0)]  # a step up at 30 min
    counts = _in_spawn(
        _insertions_per_window, str(tmp_path), str(tmp_path), profile, 3600.0, 1800.0, "uniform"
    )
    # deterministic headways: exactly the integral, 180 and 540 vehicles
    assert counts == [180, 540]
