"""V2X merging: the compiled coordination (``coord_kernel``, issue 27's eighth CPU pass) gives, bit for bit,
what the Python it replaced gives: ``time_to_go``, ``Coordinator.assign`` (fifo and cps, ties of the FCFS
key included) and the controller's whole ``_coordinate`` (``_coordinate_py``, the reference it keeps)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from corridor.addressed_channel import AddressedChannel
from corridor.channel import ChannelConfig
from corridor.controllers.merging.components import RSU, V2XMerging
from corridor.controllers.merging.coord_kernel import HAVE_C_POW, I_DRAW, ArrayCoordinator, time_to_go_c
from corridor.controllers.merging.coordinator import Coordinator, CoordinatorConfig, ZoneVehicle
from corridor.controllers.merging.trajectory import time_to_go
from corridor.vehicles.tracks.node_pool import NodeTrackPool
from tests.conftest import scenario_file

pytestmark = pytest.mark.skipif(not HAVE_C_POW, reason="the C library has no powf64 (glibc's): Python coordinator")


def test_the_compiled_time_to_go_is_pythons_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    n = 200_000
    d = rng.uniform(-5.0, 400.0, n)
    d[rng.random(n) < 0.02] = 0.0
    v0 = rng.uniform(0.0, 40.0, n)
    v_max = np.maximum(rng.uniform(1.0, 35.0, n), np.where(rng.random(n) < 0.3, v0, 0.0))
    a = rng.uniform(0.3, 3.0, n)
    got = [time_to_go_c(*x) for x in zip(d.tolist(), v0.tolist(), v_max.tolist(), a.tolist(), strict=True)]
    want = [time_to_go(*x) for x in zip(d.tolist(), v0.tolist(), v_max.tolist(), a.tolist(), strict=True)]
    assert np.array_equal(np.array(got), np.array(want))


def _zone(rng: np.random.Generator, t: float, pool: list[str], entered: dict[str, float], tie: bool) -> list[ZoneVehicle]:
    """A random zone: a subset of ``pool`` with random pictures; FCFS keys fixed at first sight (ties when
    ``tie``: newcomers share a key with each other or with a vehicle in the zone)."""
    ids = [pool[j] for j in rng.permutation(len(pool))[: int(rng.integers(0, 12))].tolist()]
    out = []
    for vid in ids:
        e = t + float(rng.uniform(0.0, 15.0))
        e = round(e, 0) if tie else e  # equal arrivals: orders of equal cost (cps's strict improvement)
        if vid not in entered:
            entered[vid] = (float(rng.choice(list(entered.values()))) if tie and entered and rng.random() < 0.5
                            else round(e, 0) if tie else e)
        out.append(ZoneVehicle(vid, "ramp" if rng.random() < 0.4 else "main", float(rng.uniform(0.0, 250.0)),
                               float(rng.uniform(0.0, 30.0)), e, entered[vid]))
    return out


@pytest.mark.parametrize("policy", ["fifo", "cps"])
@pytest.mark.parametrize("tie", [False, True])
def test_the_array_coordinator_assigns_what_the_coordinator_assigns(policy: str, tie: bool) -> None:
    rng = np.random.default_rng(11 + tie)
    for case in range(40):
        cfg = CoordinatorConfig(max_shift=int(rng.integers(0, 4)), horizon=int(rng.integers(1, 9)),
                                headway_same_s=float(rng.uniform(0.8, 2.0)), headway_cross_s=float(rng.uniform(0.8, 3.0)),
                                freeze_s=float(rng.uniform(0.0, 3.0)), weight_ramp=float(rng.uniform(0.5, 2.0)))
        py, ar = Coordinator(policy, cfg), ArrayCoordinator(policy, cfg)  # type: ignore[arg-type]
        pool = [f"v{j}" for j in range(int(rng.integers(3, 25)))]
        entered: dict[str, float] = {}
        t = 0.0
        for _ in range(60):
            t += float(rng.choice([0.1, 0.5, 2.0]))
            zone = _zone(rng, t, pool, entered, tie)
            in_zone = {z.id for z in zone}
            crossed = ({vid: t for vid in py.sequence if vid not in in_zone and rng.random() < 0.5}
                       if rng.random() < 0.9 else None)
            want = py.assign(t, zone, crossed)
            got = ar.assign(t, zone, crossed)
            assert list(got.items()) == list(want.items()), (case, t)
            assert ar.sequence == py.sequence
            assert ar.max_shift_seen == py.max_shift_seen
            st = ar.to_state()
            assert (st.n_done, st.n_ranked, st.tail) == (py._st.n_done, py._st.n_ranked, py._st.tail)


def _controller(policy: str, compiled: bool, seed: int, opens_ahead: bool) -> V2XMerging:
    bounds = {"open_ahead": {"dist_m": 150.0}} if opens_ahead else {}
    c = V2XMerging("merge", V2XMerging.Params(policy=policy, boundaries=bounds),  # type: ignore[arg-type]
                   SimpleNamespace(channels={}))
    if not compiled:  # the Python reference path
        c.coord = Coordinator(policy, c.p.coordinator)  # type: ignore[arg-type]
        c._aoi_f, c._aoi_i = np.zeros(4), np.zeros(8, dtype=np.int64)
    c.x_merge, c.y_rsu = 1000.0, -7.0
    c._rsu_pos = np.array([c.x_merge, c.y_rsu, 0.0])
    c.sensor_rng = np.random.default_rng(seed)
    return c


@pytest.mark.parametrize("policy", ["fifo", "cps"])
@pytest.mark.parametrize("opens_ahead", [False, True])
def test_the_compiled_coordination_is_the_python_coordination(policy: str, opens_ahead: bool) -> None:
    """Random ticks (rows, RSU tracks, some of them twins: FCFS ties) through both paths of two controllers."""
    rng = np.random.default_rng(5 + opens_ahead)
    channel = AddressedChannel(ChannelConfig(), np.random.default_rng(0))
    channel.attach(RSU)
    pool = [f"v{j}" for j in range(40)]
    for v in pool[::2]:
        channel.node(v)
    tracks = NodeTrackPool(channel.index, process_noise=1.0, meas_noise=0.5, vel_noise=0.3, stale_after_s=1.0)
    tracks.add_receiver(RSU)
    a, b = (_controller(policy, compiled, 3, opens_ahead) for compiled in (True, False))
    for c in (a, b):
        c.channel, c.tracks = channel, tracks
    zone_m = a.p.coordinator.control_zone_m
    t = 0.0
    for tick in range(400):
        t = round(t + 0.1, 1)
        if tick % 37 == 0:  # new nodes appear
            for v in pool[1::4][: tick // 37]:
                channel.node(v)
        ids = [pool[j] for j in rng.permutation(len(pool))[: int(rng.integers(0, 30))].tolist()]
        n = len(ids)
        dist = rng.uniform(-30.0, 400.0, n)
        dist[rng.random(n) < 0.05] = 0.0
        ramp, right, merged = rng.random(n) < 0.4, rng.random(n) < 0.6, rng.random(n) < 0.05
        connected = np.array([v in channel.index and rng.random() < 0.9 for v in ids], dtype=bool)
        s = {"ids": ids, "dist": dist, "speed": rng.uniform(0.0, 30.0, n), "ramp": ramp, "right": right,
             "merged": merged, "connected": connected, "row": dict(zip(ids, range(n)))}
        s["cand"] = np.flatnonzero((dist > 0) & (dist <= zone_m) & (ramp | right) & ~merged)
        # the RSU's tracks: some nodes tracked, twins (the same state) now and then
        nodes = sorted(channel.index.values())
        cap = max(nodes) + 1
        if tracks._row_of.shape[1] < cap:
            tracks._row_of = np.full((tracks._row_of.shape[0], 2 * cap), -1, dtype=np.int64)
        tracks._row_of[:] = -1
        twin = rng.random() < 0.2
        for r, node in enumerate(nodes[:60]):
            if rng.random() < 0.8:
                tracks._row_of[0, node] = r
                tracks.x[r] = (-rng.uniform(-10.0, 300.0), rng.uniform(-1.0, 30.0)) if not (twin and r % 3) else (-120.0, 12.5)
                tracks.t_s[r] = t - float(rng.choice([0.0, 0.1, 0.3, 1e-10, -0.1]))
        target = float(rng.uniform(8.0, 30.0))
        for c in (a, b):  # each row's channel node and key (the CAM stage's, each tick)
            c._row_nodes(s)
        got = a._coordinate(t, dict(s), target)
        want = b._coordinate(t, dict(s), target)
        assert got[0] == want[0], tick
        assert [(x[0], x[1], x[3]) for x in got[1]] == [(x[0], x[1], x[3]) for x in want[1]], tick
        assert a.coord.sequence == b.coord.sequence
        assert (a._aoi_sum, a._aoi_n, a._aoi_max) == (b._aoi_sum, b._aoi_n, b._aoi_max)
        assert _next_draw(a) == _next_draw(b)  # the same sensor draws taken (in batches by the compiled path)
    assert isinstance(a.coord, ArrayCoordinator) and a._aoi_n > 100 and math.isfinite(a._aoi_max)


def _next_draw(c: V2XMerging) -> float:
    """The next standard normal the controller's sensor readings would take (without taking it)."""
    if isinstance(c.coord, ArrayCoordinator):
        at = int(c.coord.si[I_DRAW])
        if at < len(c._draws):
            return float(c._draws[at])
    state = c.sensor_rng.bit_generator.state
    z = float(c.sensor_rng.standard_normal())
    c.sensor_rng.bit_generator.state = state
    return z


def test_without_the_c_librarys_powf64_the_python_coordinator_gives_the_same_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the C library has no powf64 (macOS, musl) the controller keeps the Python coordinator, and the run is
    the compiled one's: metrics and mode events the same."""
    from corridor.controllers.merging import components
    from corridor.run import simulate
    from corridor.scenario import load
    from corridor.variants import variant_scenarios

    def run() -> tuple[dict, list]:
        sc, _ = load(scenario_file("merging"), ["duration=90", "warmup=20", "outputs.signals=false"])
        metrics, ctx, _ = simulate(variant_scenarios(sc)["v2x_cps"], 0)
        return metrics, [(e.t, e.message) for e in ctx.events.of_kind("mode")]

    compiled = run()
    monkeypatch.setattr(components, "HAVE_C_POW", False)

    def compiled_call(*a: object) -> None:
        raise AssertionError("the compiled coordinator ran")

    monkeypatch.setattr(components, "coordinate_into", compiled_call)
    python = run()
    same = lambda a, b: a == b or (a != a and b != b)  # noqa: E731  (NaN == NaN)
    assert compiled[0].keys() == python[0].keys() and all(same(compiled[0][k], python[0][k]) for k in compiled[0])
    assert compiled[1] == python[1] and len(compiled[1]) > 10
    assert compiled[0]["v2x_commands"] > 0
