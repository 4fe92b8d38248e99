"""``v2x_merge_gaps``'s compiled pairing and slot planning (``gap_kernel.plan_slots``) against the Python
it replaces (``GapMerging._slots_py``), bit for bit, on random drives: the slots (times, the RSU's view of
leader, partner and ramp vehicle), the pairs and their order, the slots kept, the events and the state of
both sensor generators after every tick."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.controllers.merging.gap_components import GapMerging
from corridor.controllers.merging.gap_kernel import HAVE_C_POW, cfg_array
from corridor.events import EventLog

pytestmark = pytest.mark.skipif(not HAVE_C_POW, reason="the compiled planning needs glibc's powf64")

MERGE_X, CROSS_X = 600.0, 700.0


def _controller(params: GapMerging.Params, seed: int) -> GapMerging:
    c = GapMerging("gaps", params, SimpleNamespace(channels={}))
    c.merge_x, c.cross_x, c.cos_ramp = MERGE_X, CROSS_X, math.cos(math.radians(12.0))
    c.pos_rng, c.sensor_rng = np.random.default_rng(seed), np.random.default_rng(seed + 1)
    c.events = EventLog()
    c._plan_cfg = cfg_array(params, c.merge_x, c.cross_x, c.cos_ramp)
    return c


class _Drive:
    """Vehicles on a highway line and a ramp (fronts in [0, 760] m), moving, entering and leaving."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.serial = 0
        self.veh: dict[str, list[Any]] = {}  # id -> [front, speed, length, connected, ramp role, on ramp]
        for _ in range(int(rng.integers(5, 40))):
            self._add(float(rng.uniform(0.0, 760.0)))

    def _add(self, front: float) -> None:
        rng = self.rng
        ramp = bool(rng.random() < 0.3)
        on_ramp = ramp and front < CROSS_X and rng.random() < 0.9
        speed = 0.0 if rng.random() < 0.1 else float(rng.uniform(0.0, 32.0))
        self.veh[f"v{self.serial}"] = [front, speed, float(rng.choice([4.5, 5.0, 7.5])), bool(rng.random() < 0.5),
                                       ramp, on_ramp]
        self.serial += 1

    def step(self) -> None:
        rng = self.rng
        for vid, v in list(self.veh.items()):
            v[0] += v[1] * 0.5 * float(rng.uniform(0.5, 1.5))
            v[1] = max(0.0, v[1] + float(rng.normal(0.0, 1.5)))
            if v[5] and v[0] >= MERGE_X and rng.random() < 0.5:
                v[5] = False
            if v[0] > 760.0 or rng.random() < 0.02:
                del self.veh[vid]
        for _ in range(int(rng.integers(0, 3))):
            self._add(float(rng.uniform(0.0, 200.0)) if rng.random() < 0.7 else float(rng.uniform(0.0, 760.0)))
        if rng.random() < 0.2:  # twins: equal fronts, ties in every sort
            vs = list(self.veh.values())
            if len(vs) >= 2:
                a, b = rng.choice(len(vs), 2, replace=False)
                vs[b][0] = vs[a][0] + (0.1 if rng.random() < 0.5 else 0.0)  # + 0.1: on the leader test's edge
                vs[b][1] = vs[a][1]

    def state(self) -> dict[str, Any]:
        ids = list(self.veh)
        a = np.array([self.veh[v][:3] for v in ids], dtype=float).reshape(len(ids), 3)
        size = np.column_stack([a[:, 2], np.full(len(ids), 1.8)])
        b = np.array([self.veh[v][3:] for v in ids], dtype=bool).reshape(len(ids), 3)
        return {"ids": ids, "front": a[:, 0].copy(), "speed": a[:, 1].copy(), "length": size[:, 0],
                "connected": b[:, 0].copy(), "ramp": b[:, 1].copy(), "on_ramp": b[:, 2].copy()}


PARAMS = [
    GapMerging.Params(),
    GapMerging.Params(human_margin_s=0.5, ramp_time_gap_s=1.0, open_time_gap_s=1.0, restart_gap_s=1.0,
                      partner_min_speed_mps=5.0, pair_zone_m=300.0, min_run_speed_mps=6.0, commit_m=120.0,
                      pair_queue_head_only=False),
    GapMerging.Params(ramp_time_gap_s=0.0, open_time_gap_s=3.0, restart_partner_speed_mps=25.0, plan_accel_mps2=0.4,
                      ramp_sensor_noise_m=0.0, sensor_noise_mps=0.0),
    GapMerging.Params(lead_close_up=True),  # the gap made from ahead (connected leaders close up)
    GapMerging.Params(lead_close_up=True, lead_time_gap_s=0.6, lead_ramp_gap_s=0.0, a_max_mps2=3.0, u_max_mps=20.0,
                      open_time_gap_s=1.0, human_margin_s=0.5, pair_queue_head_only=False),
]


@pytest.mark.parametrize("which", range(len(PARAMS)))
def test_compiled_planning_is_the_python_planning(which: int) -> None:
    params = PARAMS[which]
    rng = np.random.default_rng(100 + which)
    n_ticks = n_pairs = n_new = n_dropped = n_leaders = 0
    for drive_no in range(25):
        drive = _Drive(rng)
        ref, got = _controller(params, drive_no), _controller(params, drive_no)
        for tick in range(80):
            t = 0.5 * tick
            v_cross = float(rng.choice([15.0, 9.5, float(rng.uniform(2.0, 15.0))]))
            s_ref, s_got = drive.state(), drive.state()
            before = dict(ref.pairs)
            slots_ref = ref._slots_py(t, s_ref, v_cross)
            slots_got = got._slots(t, s_got, v_cross)
            assert slots_got == slots_ref, (drive_no, tick)
            assert list(slots_got) == list(slots_ref)
            assert list(got.pairs.items()) == list(ref.pairs.items())
            assert got._t_slot == ref._t_slot
            assert list(got.leaders.items()) == list(ref.leaders.items())
            assert not got._dropped and not ref._dropped
            assert got.events.events == ref.events.events
            assert got.pos_rng.bit_generator.state == ref.pos_rng.bit_generator.state
            assert got.sensor_rng.bit_generator.state == ref.sensor_rng.bit_generator.state
            n_ticks += 1
            n_pairs += len(slots_ref)
            n_new += len(set(ref.pairs) - set(before))
            n_dropped += len(set(before) - set(ref.pairs))
            n_leaders += len(ref.leaders)
            drive.step()
    assert n_ticks == 2000 and n_pairs > 300 and n_new > 50 and n_dropped > 50, (n_pairs, n_new, n_dropped)
    assert (n_leaders > 100) == params.lead_close_up, n_leaders  # slots behind connected leaders: with the option


def test_the_run_test_squares_as_python() -> None:
    """The test of a ramp vehicle on its run (``v ** 2``, the C library's pow) at its edge: distances equal
    to Python's bound and one step either side, speeds where pow(v, 2) and v * v differ."""
    from corridor.controllers.merging.gap_kernel import _running

    params = GapMerging.Params()
    cfg = cfg_array(params, MERGE_X, CROSS_X, 1.0)
    rng = np.random.default_rng(7)
    b2 = 2.0 * params.b_comfort_mps2
    n_apart = 0
    for v in rng.uniform(0.0, 40.0, 20000).tolist():
        bound = v ** 2 / b2 + params.commit_m
        n_apart += bound != v * v / b2 + params.commit_m
        for d in (bound, math.nextafter(bound, math.inf), math.nextafter(bound, -math.inf)):
            ref = v >= params.min_run_speed_mps and d <= v ** 2 / (2.0 * params.b_comfort_mps2) + params.commit_m
            assert _running(cfg, v, d, b2) == ref, (v, d)
    assert n_apart > 0  # the cases where x * x would give another answer are among them


def test_ramp_leaders_of_a_tick_are_the_ramp_leader() -> None:
    """``_ramp_leaders`` (one sort a tick) against ``_ramp_leader`` (a search per vehicle) for every row:
    fronts tied, 1e-6 m apart (the search's edge) and apart; vehicles off the ramp."""
    c = _controller(GapMerging.Params(), 0)
    rng = np.random.default_rng(11)
    n_found = 0
    for _ in range(3000):
        n = int(rng.integers(1, 30))
        front = rng.uniform(300.0, 700.0, n)
        for _ in range(int(rng.integers(0, 4))):  # ties and the 1e-6 m edge
            a, b = rng.integers(0, n, 2)
            front[b] = front[a] + float(rng.choice([0.0, 1e-6, 2e-6]))
        s = {"front": front, "on_ramp": rng.random(n) < 0.6, "length": rng.choice([4.5, 5.0, 7.5], n),
             "speed": rng.uniform(0.0, 20.0, n)}
        leader = c._ramp_leaders(s, front.tolist(), s["speed"].tolist())
        for k in range(n):
            ref = c._ramp_leader(s, k)
            assert leader(k) == ref, (k, front, s["on_ramp"])
            n_found += math.isfinite(ref[0])
    assert n_found > 10000


def test_merge_speed_is_numpys_mean() -> None:
    """``_merge_speed`` (Python floats) against numpy's mean of the finite cells in the 100 m before the merge."""
    c = _controller(GapMerging.Params(), 0)
    rng = np.random.default_rng(12)
    for cell_m in (50.0, 20.0, 10.0, 7.0):  # 2 to 14 cells in the window: numpy's pairwise sum from 8 on
        c.cells = np.arange(MERGE_X - 300.0, 760.0, cell_m) + 0.5 * cell_m
        c._near_cells = np.flatnonzero((c.cells < c.merge_x) & (c.cells > c.merge_x - 100.0))
        for _ in range(3000):
            cs = rng.uniform(0.0, 30.0, len(c.cells)) * 10.0 ** rng.integers(-2, 2, len(c.cells))
            cs[rng.random(len(cs)) < 0.3] = np.nan
            near = np.isfinite(cs) & (c.cells < c.merge_x) & (c.cells > c.merge_x - 100.0)
            ref = float(np.mean(cs[near])) if near.any() else c.p.u_max_mps
            assert c._merge_speed(cs) == ref


def test_projected_position_on_floats_is_projected() -> None:
    """The ramp commands' projected x (one row at a time, Python floats) is ``_projected``'s (numpy)."""
    c = _controller(GapMerging.Params(), 0)
    rng = np.random.default_rng(13)
    front = rng.uniform(0.0, 760.0, 20000)
    on = rng.random(20000) < 0.5
    ref = c._projected({"front": front, "on_ramp": on}).tolist()
    got = [c.merge_x - (c.merge_x - f) / c.cos_ramp if o else f for f, o in zip(front.tolist(), on.tolist(), strict=True)]
    assert got == ref


def test_tick_rows_are_the_numpy_masks() -> None:
    """``_receiver_rows`` (``gap_kernel.tick_rows``: one pass) against ``_receivers``' mask (numpy) with the
    partners, and the connected ramp vehicles' and the ramp's rows against ``np.flatnonzero``: on the zone's
    edges, NaN fronts, partners gone from the road."""
    rng = np.random.default_rng(14)
    n_recv = n_partner = 0
    for params in (GapMerging.Params(), GapMerging.Params(zone_before_m=150.0, release_after_m=0.0)):
        c = _controller(params, 0)
        lo, hi = MERGE_X - params.zone_before_m, MERGE_X + params.release_after_m
        c._zone = (lo, hi)
        for _ in range(3000):
            drive = _Drive(rng)
            s = drive.state()
            n = len(s["ids"])
            edges = np.array([lo, hi, CROSS_X, np.nan, np.nextafter(lo, 0.0), np.nextafter(hi, 1e9)])
            pick = rng.random(n) < 0.2
            s["front"][pick] = rng.choice(edges, int(pick.sum()))
            c.pairs = {f"r{q}": (s["ids"][int(rng.integers(0, n))] if n and rng.random() < 0.8 else "gone")
                       for q in range(int(rng.integers(0, 4)))}
            ref = {k: v.copy() for k, v in s.items() if k != "ids"} | {"ids": s["ids"]}
            got = c._receiver_rows(s)
            assert got.tolist() == np.flatnonzero(c._receivers(ref)).tolist()
            assert s["_cramp"] == np.flatnonzero(ref["connected"] & ref["ramp"]).tolist()
            assert s["_onramp"] == np.flatnonzero(ref["on_ramp"]).tolist()
            n_recv += len(got)
            n_partner += len(c.pairs)
    assert n_recv > 10000 and n_partner > 3000


def _queue(vehicles: list[tuple[str, float, float, bool, bool]]) -> dict[str, Any]:
    """A state of (id, front [m], speed [m/s], connected, on the ramp) vehicles (ramp vehicles: those on it)."""
    return {"ids": [v[0] for v in vehicles], "front": np.array([v[1] for v in vehicles]),
            "speed": np.array([v[2] for v in vehicles]), "length": np.full(len(vehicles), 5.0),
            "connected": np.array([v[3] for v in vehicles]), "ramp": np.array([v[4] for v in vehicles]),
            "on_ramp": np.array([v[4] for v in vehicles])}


@pytest.mark.parametrize("compiled", [False, True])
def test_a_connected_ramp_vehicle_behind_a_human_one_gets_no_partner(compiled: bool) -> None:
    """``pair_queue_head_only``: a connected ramp vehicle with an unconnected vehicle ahead of it on the ramp
    gets no partner and no slot (it waits behind that driver at the yield line anyway); the one at the head
    of the ramp does, and so does the one behind once the human has left the ramp; with the option off both
    are paired (the former behaviour).  Both the Python planning and the compiled one."""
    quiet = {"ramp_sensor_noise_m": 0.0, "sensor_noise_mps": 0.0}
    highway = [("p1", 300.0, 25.0, True, False), ("p2", 200.0, 25.0, True, False), ("p3", 100.0, 25.0, True, False)]

    def plan(params: GapMerging.Params, vehicles: list[tuple[str, float, float, bool, bool]]) -> GapMerging:
        c = _controller(params, 0)
        slots = c._slots(0.0, _queue(vehicles), 15.0) if compiled else c._slots_py(0.0, _queue(vehicles), 15.0)
        assert set(slots) == set(c.pairs)
        return c

    head = [("c_head", 570.0, 8.0, True, True), ("h", 550.0, 8.0, False, True), ("c_back", 530.0, 8.0, True, True)]
    c = plan(GapMerging.Params(**quiet), highway + head)
    assert "c_head" in c.pairs and "c_back" not in c.pairs  # the one behind the human: no partner
    c = plan(GapMerging.Params(**quiet, pair_queue_head_only=False), highway + head)
    assert "c_head" in c.pairs and "c_back" in c.pairs
    gone = [v for v in head if v[0] != "h"]  # the human has merged: the connected one is at the head now
    c = plan(GapMerging.Params(**quiet), highway + gone)
    assert "c_back" in c.pairs
    on_hw = [*gone, ("h", 620.0, 8.0, False, False)]  # past the ramp (on the highway): no longer ahead on it
    c = plan(GapMerging.Params(**quiet), highway + on_hw)
    assert "c_back" in c.pairs
