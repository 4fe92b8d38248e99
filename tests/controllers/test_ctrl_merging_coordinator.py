"""Merge coordinator: FIFO order and headways; CPS lowers delay within its position-shift bound."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.merging.coordinator import Coordinator, CoordinatorConfig, ZoneVehicle, jain_index

V_FREE_MPS = 20.0


def _zv(
    vid: str, road: str, entered_s: float, cfg: CoordinatorConfig, earliest_s: float | None = None
) -> ZoneVehicle:
    t_free = entered_s + cfg.control_zone_m / V_FREE_MPS
    return ZoneVehicle(
        vid, road, cfg.control_zone_m, V_FREE_MPS, t_free if earliest_s is None else earliest_s, entered_s
    )


def _arrivals(rng: np.random.Generator, rate_main: float, rate_ramp: float, t_end_s: float) -> list[tuple]:
    """Poisson arrivals at the control-zone entry: (entered_s, id, road), sorted."""
    out = []
    for road, rate in (("main", rate_main), ("ramp", rate_ramp)):
        times = np.cumsum(rng.exponential(1.0 / rate, int(3 * rate * t_end_s) + 10))
        out += [(float(t), f"{road}{k}", road) for k, t in enumerate(times[times < t_end_s])]
    return sorted(out)


def _simulate(policy: str, arrivals: list[tuple], cfg: CoordinatorConfig, dt_s: float = 0.2) -> dict:
    """Point-queue zone: vehicles enter, get times every tick, leave when their time has come."""
    coord = Coordinator(policy, cfg)
    info = {vid: (t_in, road) for t_in, vid, road in arrivals}
    crossed: dict[str, tuple[float, float, str]] = {}  # id -> (crossing time, delay, road)
    order: list[str] = []
    active: list[str] = []
    i, t = 0, 0.0
    while i < len(arrivals) or active:
        while i < len(arrivals) and arrivals[i][0] <= t:
            active.append(arrivals[i][1])
            i += 1
        times = coord.assign(t, [_zv(v, info[v][1], info[v][0], cfg) for v in active])
        for v in sorted(active, key=lambda v: times[v]):
            if times[v] <= t:
                t_free = info[v][0] + cfg.control_zone_m / V_FREE_MPS
                crossed[v] = (times[v], times[v] - t_free, info[v][1])
                order.append(v)
        active = [v for v in active if v not in crossed]
        t += dt_s
    return {"crossed": crossed, "order": order, "coord": coord}


def _delays(res: dict) -> tuple[np.ndarray, np.ndarray]:
    d = np.array([c[1] for c in res["crossed"].values()])
    ramp = np.array([c[2] == "ramp" for c in res["crossed"].values()])
    return d, ramp


def _check_headways(res: dict, cfg: CoordinatorConfig) -> None:
    seq = sorted(res["crossed"].items(), key=lambda kv: kv[1][0])
    for (_, (t_a, _, road_a)), (_, (t_b, _, road_b)) in zip(seq, seq[1:]):
        h = cfg.headway_same_s if road_a == road_b else cfg.headway_cross_s
        assert t_b - t_a >= h - 1e-9


def test_fifo_order_and_headways_closed_form() -> None:
    cfg = CoordinatorConfig(control_zone_m=200.0, headway_same_s=1.0, headway_cross_s=2.0)
    coord = Coordinator("fifo", cfg)
    vs = [_zv("m1", "main", 0.0, cfg), _zv("r1", "ramp", 0.1, cfg), _zv("m2", "main", 0.2, cfg)]
    times = coord.assign(0.2, vs[::-1])  # input order must not matter
    assert coord.sequence == ["m1", "r1", "m2"]
    # earliest: 10.0, 10.1, 10.2 s; headways main->ramp 2 s, ramp->main 2 s
    assert times == pytest.approx({"m1": 10.0, "r1": 12.0, "m2": 14.0})
    # a later arrival goes to the back; earlier assignments do not move
    times2 = coord.assign(1.0, vs + [_zv("m3", "main", 1.0, cfg)])
    assert times2 == pytest.approx({"m1": 10.0, "r1": 12.0, "m2": 14.0, "m3": 15.0})
    # everyone crossed and left: a late arrival still keeps the headway to the last crossing (m3, 15 s)
    times3 = coord.assign(15.5, [_zv("r9", "ramp", 15.5, cfg, earliest_s=15.5)])
    assert times3 == pytest.approx({"r9": 15.0 + 2.0})


def test_fifo_repairs_a_missed_slot_and_pushes_followers() -> None:
    cfg = CoordinatorConfig(control_zone_m=200.0, headway_same_s=1.0, headway_cross_s=2.0, repair_tol_s=0.3)
    coord = Coordinator("fifo", cfg)
    vs = [_zv("a", "main", 0.0, cfg), _zv("b", "main", 0.5, cfg)]
    assert coord.assign(0.5, vs) == pytest.approx({"a": 10.0, "b": 11.0})
    slow = [_zv("a", "main", 0.0, cfg, earliest_s=10.2), vs[1]]  # within tolerance: keep
    assert coord.assign(1.0, slow) == pytest.approx({"a": 10.0, "b": 11.0})
    slower = [_zv("a", "main", 0.0, cfg, earliest_s=12.0), vs[1]]
    assert coord.assign(1.5, slower) == pytest.approx({"a": 12.0, "b": 13.0})


def test_fifo_rolling_simulation_keeps_order_and_headways() -> None:
    cfg = CoordinatorConfig()
    arr = _arrivals(np.random.default_rng(11), 0.4, 0.15, 200.0)
    res = _simulate("fifo", arr, cfg)
    fcfs = [vid for _, vid, _ in arr]
    assert res["order"] == fcfs
    _check_headways(res, cfg)
    assert res["coord"].max_shift_seen == 0


@pytest.mark.parametrize(("rate_main", "rate_ramp", "seed"), [(0.5, 0.2, 0), (0.6, 0.1, 1)])
def test_cps_lowers_total_delay_within_shift_bound(rate_main: float, rate_ramp: float, seed: int) -> None:
    """Congested demand with a mainline/ramp imbalance: CPS groups same-road vehicles."""
    cfg = CoordinatorConfig(max_shift=2)
    arr = _arrivals(np.random.default_rng(seed), rate_main, rate_ramp, 300.0)
    fifo, cps = _simulate("fifo", arr, cfg), _simulate("cps", arr, cfg)
    d_f, ramp_f = _delays(fifo)
    d_c, ramp_c = _delays(cps)
    assert len(d_c) == len(d_f) == len(arr)
    assert d_c.sum() < 0.85 * d_f.sum()  # at least 15 % less total delay
    _check_headways(cps, cfg)
    # fairness bound: nobody crosses more than K positions away from its FCFS position
    pos = {vid: k for k, vid in enumerate(cps["order"])}
    shifts = [abs(pos[vid] - k) for k, (_, vid, _) in enumerate(arr)]
    assert max(shifts) <= cfg.max_shift and cps["coord"].max_shift_seen <= cfg.max_shift
    # Jain's index between the mean ramp and mainline delays, both policies
    j_fifo = jain_index([d_f[~ramp_f].mean(), d_f[ramp_f].mean()])
    j_cps = jain_index([d_c[~ramp_c].mean(), d_c[ramp_c].mean()])
    assert j_cps > 0.9 and j_fifo > 0.9
    assert d_c.min() >= -1e-9  # nobody crosses before its earliest arrival


def test_cps_equals_fifo_when_shifts_are_forbidden() -> None:
    cfg = CoordinatorConfig(max_shift=0)
    arr = _arrivals(np.random.default_rng(5), 0.4, 0.2, 120.0)
    a, b = _simulate("fifo", arr, cfg), _simulate("cps", arr, cfg)
    assert a["order"] == b["order"]
    assert _delays(a)[0] == pytest.approx(_delays(b)[0])


def test_jain_index_values() -> None:
    assert jain_index([3.0, 3.0]) == pytest.approx(1.0)
    assert jain_index([1.0, 0.0]) == pytest.approx(0.5)
    assert jain_index([0.0, 0.0]) == 1.0
    with pytest.raises(ValueError):
        Coordinator("greedy")  # type: ignore[arg-type]


def test_a_vehicle_that_leaves_without_crossing_frees_its_slot() -> None:
    """A lane change out of the conflict must not hold back the vehicles behind it."""
    cfg = CoordinatorConfig(control_zone_m=200.0, headway_same_s=1.0, headway_cross_s=2.0, repack_tol_s=0.5)
    coord = Coordinator("fifo", cfg)
    vs = [_zv("a", "main", 0.0, cfg), _zv("b", "main", 0.1, cfg, earliest_s=10.1), _zv("c", "main", 0.2, cfg)]
    assert coord.assign(0.2, vs) == pytest.approx({"a": 10.0, "b": 11.0, "c": 12.0})
    # a changes lanes (gone, not crossed): b and c move up to what they can make
    times = coord.assign(0.3, vs[1:], crossed_s={})
    assert times == pytest.approx({"b": 10.1, "c": 11.1})
    # b crosses late (measured 10.8 s): c keeps the headway to the measured crossing, not to b's slot
    times = coord.assign(10.8, vs[2:], crossed_s={"b": 10.8})
    assert times == pytest.approx({"c": 11.8})


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cps_never_lets_a_follower_pass_its_leader_on_the_same_road(seed: int) -> None:
    cfg = CoordinatorConfig(max_shift=2)
    arr = _arrivals(np.random.default_rng(seed), 0.5, 0.25, 200.0)
    res = _simulate("cps", arr, cfg)
    for road in ("main", "ramp"):
        fcfs = [vid for _, vid, r in arr if r == road]
        assert [vid for vid in res["order"] if res["crossed"][vid][2] == road] == fcfs


def test_fifo_serves_first_at_the_merge_point_not_first_into_the_zone() -> None:
    """A slow ramp vehicle that entered the zone first but is expected at the merge point later does
    not hold a mainline vehicle that entered after it and is expected earlier (first come, first served
    at the merge point: the order of ``entered_s``, the arrival expected at zone entry).  Before the fix
    fifo appended every newcomer behind the whole sequence: the mainline vehicle was ordered behind the
    ramp vehicle and had to yield to it, 8 s after it could have crossed."""
    cfg = CoordinatorConfig(control_zone_m=250.0, headway_same_s=1.0, headway_cross_s=1.4)
    coord = Coordinator("fifo", cfg)
    ramp = ZoneVehicle("r1", "ramp", 250.0, 12.0, earliest_arrival_s=16.0, entered_s=16.0)
    assert coord.assign(0.0, [ramp]) == pytest.approx({"r1": 16.0})
    main = ZoneVehicle("m1", "main", 250.0, 30.0, earliest_arrival_s=9.3, entered_s=9.3)
    times = coord.assign(1.0, [ramp, main])
    assert coord.sequence == ["m1", "r1"]
    assert times == pytest.approx({"m1": 9.3, "r1": 16.0})


def test_fifo_never_moves_a_newcomer_ahead_of_a_committed_slot() -> None:
    """A vehicle within ``freeze_s`` of its slot keeps its place, even against an earlier expected arrival."""
    cfg = CoordinatorConfig(control_zone_m=250.0, headway_same_s=1.0, headway_cross_s=1.4, freeze_s=2.0)
    coord = Coordinator("fifo", cfg)
    coord.assign(0.0, [ZoneVehicle("r1", "ramp", 20.0, 15.0, earliest_arrival_s=1.5, entered_s=1.5)])
    late = ZoneVehicle("m1", "main", 25.0, 30.0, earliest_arrival_s=0.9, entered_s=0.9)  # heard late
    times = coord.assign(0.1, [ZoneVehicle("r1", "ramp", 18.5, 15.0, 1.5, 1.5), late])
    assert coord.sequence == ["r1", "m1"]
    assert times == pytest.approx({"r1": 1.5, "m1": 2.9})


def test_fifo_rolling_simulation_crosses_in_order_of_expected_arrival() -> None:
    """Ramp vehicles cross the zone slower than mainline ones: the crossing order is the order of the
    arrivals expected at zone entry, not of the zone entries (before the fix: the entry order)."""
    cfg = CoordinatorConfig()
    arr = _arrivals(np.random.default_rng(3), 0.4, 0.15, 200.0)
    v_road = {"main": 30.0, "ramp": 12.0}  # [m/s] through the zone
    expected = {vid: t_in + cfg.control_zone_m / v_road[road] for t_in, vid, road in arr}
    coord = Coordinator("fifo", cfg)
    crossed: list[str] = []
    active: list[tuple[str, str]] = []
    i, t = 0, 0.0
    while i < len(arr) or active:
        while i < len(arr) and arr[i][0] <= t:
            active.append((arr[i][1], arr[i][2]))
            i += 1
        zone = [ZoneVehicle(v, r, 0.0, v_road[r], max(expected[v], t), expected[v]) for v, r in active]
        times = coord.assign(t, zone)
        done = sorted((v for v, _ in active if times[v] <= t), key=lambda v: times[v])
        crossed += done
        active = [(v, r) for v, r in active if v not in done]
        t += 0.2
    assert len(crossed) == len(arr)
    assert crossed == sorted(expected, key=lambda v: (expected[v], v))
