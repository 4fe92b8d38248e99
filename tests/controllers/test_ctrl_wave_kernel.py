"""``v2x_wave_damping``'s compiled tick (``wave_kernel.wave_tick``) against the Python it replaces, bit for
bit on random inputs: the safety layer and the FollowerStopper against ``safety_layer`` and
``wave_damping``, the law against ``WaveDamping._speed``, and the controller's compiled tick against
``_communicate`` + ``_decide`` on random drives (channels with loss, long delays, overflow, out of range,
end-of-run drops): every command, event, counter, message received, the channel's statistics and the
state of the sensor and channel generators after every tick."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.channel import BernoulliLoss, ChannelConfig
from corridor.controllers.merging import wave_kernel as wk
from corridor.controllers.merging.safety_layer import SafetyParams, safe_accel
from corridor.controllers.merging.wave_components import WaveDamping
from corridor.controllers.merging.wave_damping import StopperParams, follower_stopper
from corridor.events import EventLog

pytestmark = pytest.mark.skipif(not wk.HAVE_C_POW, reason="the compiled tick needs glibc's powf64")

MERGE_X, END_X = 600.0, 760.0


def _values(rng: np.random.Generator, n: int, lo: float, hi: float) -> np.ndarray:
    """Values in [lo, hi) at magnitudes apart (rounding shows), some exactly 0 and some equal."""
    v = rng.uniform(lo, hi, n) * 10.0 ** rng.integers(-2, 1, n)
    v[rng.random(n) < 0.05] = 0.0
    return v


def test_safe_accel_is_the_safety_layer() -> None:
    rng = np.random.default_rng(1)
    n = 0
    for reaction, b_ego, b_lead, s0 in [(0.5, 6.0, 8.0, 2.0), (0.3, 9.0, 7.5, 0.0), (1.0, 2.0, 2.0, 4.0)]:
        p = SafetyParams(reaction_s=reaction, b_ego_mps2=b_ego, b_lead_mps2=b_lead, s0_m=s0)
        gaps, vs, vls, acs = (_values(rng, 40000, -5.0, 120.0), _values(rng, 40000, 0.0, 35.0),
                              _values(rng, 40000, 0.0, 35.0), rng.uniform(-8.0, 3.0, 40000))
        gaps[:50] = math.inf
        for g, v, vl, a in zip(gaps.tolist(), vs.tolist(), vls.tolist(), acs.tolist(), strict=True):
            ref = safe_accel(g, v, vl, a, p)
            got = wk.safe_accel_c(g, v, vl, a, reaction, b_ego, b_lead, s0)
            assert got == ref or (math.isnan(got) and math.isnan(ref)), (g, v, vl, a)
            n += got != a
    assert n > 10000  # the bound binds often
    # at the edge of reach (gap = s0): the leader's v ** 2 (C's pow, not v * v) shows in the result
    p = SafetyParams(reaction_s=0.5, b_ego_mps2=6.0, b_lead_mps2=8.0, s0_m=2.0)
    n_apart = 0
    for vl in rng.uniform(0.0, 40.0, 200000).tolist():
        if vl ** 2 == vl * vl:
            continue
        for g, v in ((2.0, 0.0), (2.0, 0.5 * vl)):
            ref = safe_accel(g, v, vl, 5.0, p)
            got = wk.safe_accel_c(g, v, vl, 5.0, 0.5, 6.0, 8.0, 2.0)
            assert got == ref, (g, v, vl)
            n_apart += ref != safe_accel(g, v, math.nextafter(vl * vl, math.inf) ** 0.5, 5.0, p)
    assert n_apart > 0


def test_follower_stopper_is_wave_dampings() -> None:
    rng = np.random.default_rng(2)
    p = StopperParams()
    cfg = np.zeros(wk.N_CFG)
    (cfg[wk.C_DX0_1], cfg[wk.C_DX0_2], cfg[wk.C_DX0_3]), (cfg[wk.C_D_1], cfg[wk.C_D_2], cfg[wk.C_D_3]) = p.dx0_m, p.d_mps2
    cfg[wk.C_TIME_GAP] = p.time_gap_s
    for g, v, vl, u in zip(_values(rng, 100000, 0.0, 60.0).tolist(), _values(rng, 100000, 0.0, 35.0).tolist(),
                           _values(rng, 100000, -1.0, 35.0).tolist(), _values(rng, 100000, 0.0, 30.0).tolist(), strict=True):
        assert wk.follower_stopper_c(g, v, vl, u, cfg) == follower_stopper(g, v, vl, u, p), (g, v, vl, u)


def _ctx(duration: float, seed: int) -> Any:
    lm = SimpleNamespace(kind="flow_merge", merge_x=MERGE_X, mainline_end_x=END_X, past_merge_x=MERGE_X + 100.0,
                         ramp_angle_deg=12.0, is_ramp_lane=lambda name: name.startswith("ramp"))
    road = SimpleNamespace(tables=SimpleNamespace(landmarks=lm))
    return SimpleNamespace(snapshot=SimpleNamespace(road=road), duration=duration, scenario=None, events=EventLog(),
                           rng=lambda name: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(len(name),))))


def _controller(params: WaveDamping.Params, chan: ChannelConfig, duration: float, seed: int, compiled: bool) -> WaveDamping:
    c = WaveDamping("wave", params, SimpleNamespace(channels={"v2x": chan}))
    c.period = 0.5
    c.setup(_ctx(duration, seed))
    assert c.compiled
    c.compiled = compiled
    return c


class _Drive:
    """Vehicles on a highway line and a ramp lane (fronts in [0, 760] m), moving, entering and leaving."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng, self.serial, self.n_states = rng, 0, 0
        self.veh: dict[str, list[Any]] = {}  # id -> [front, speed, length, connected, ramp role, on ramp, y]
        for _ in range(int(rng.integers(0, 40))):
            self._add(float(rng.uniform(0.0, END_X)))

    def _add(self, front: float) -> None:
        rng = self.rng
        if rng.random() < 0.15:  # on a 5 m grid: cell edges, centres and centres - horizon (the law's edges)
            front = 5.0 * float(rng.integers(0, 152))
        ramp = bool(rng.random() < 0.2)
        speed = 0.0 if rng.random() < 0.1 else float(rng.uniform(0.0, 32.0))
        self.veh[f"v{self.serial}"] = [front, speed, float(rng.choice([4.5, 5.0, 7.5])), bool(rng.random() < 0.5), ramp,
                                       ramp and front < MERGE_X, float(rng.choice([0.0, 0.0, 40.0, 400.0]))]
        self.serial += 1

    def step(self) -> None:
        rng = self.rng
        for vid, v in list(self.veh.items()):
            v[0] += v[1] * 0.5 * float(rng.uniform(0.0, 1.5))
            v[1] = max(0.0, v[1] + float(rng.normal(0.0, 2.0)))
            if v[5] and v[0] >= MERGE_X:
                v[5] = False
            if v[0] > END_X or rng.random() < 0.02:
                del self.veh[vid]
        for _ in range(int(rng.integers(0, 3))):
            self._add(float(rng.uniform(0.0, 200.0)) if rng.random() < 0.7 else float(rng.uniform(0.0, END_X)))
        if rng.random() < 0.3 and self.veh:
            self.veh[list(self.veh)[int(rng.integers(0, len(self.veh)))]][0] = 5.0 * float(rng.integers(0, 152))
        if rng.random() < 0.2 and len(self.veh) >= 2:  # twins: equal fronts, ties in the sort
            vs = list(self.veh.values())
            a, b = rng.choice(len(vs), 2, replace=False)
            vs[b][0] = vs[a][0]

    def state(self) -> dict[str, Any]:
        self.n_states += 1
        if self.n_states % 5 == 0:  # the same vehicles in other rows (the snapshot's order may change)
            self.veh = dict(reversed(list(self.veh.items())))
        ids = list(self.veh)
        a = np.array([[v[0], v[1], v[2], v[6]] for v in self.veh.values()], dtype=float).reshape(len(ids), 4)
        b = np.array([v[3:6] for v in self.veh.values()], dtype=bool).reshape(len(ids), 3)
        pos = np.column_stack([a[:, 0] - 2.0, a[:, 3], np.zeros(len(ids))])
        if len(ids) and self.rng.random() < 0.1:
            pos[self.rng.integers(0, len(ids))] = np.nan  # not range checked
        return {"ids": ids, "front": a[:, 0].copy(), "length": a[:, 2].copy(), "speed": a[:, 1].copy(),
                "on_ramp": b[:, 2].copy(), "ramp": b[:, 1].copy(), "connected": b[:, 0].copy(), "pos": pos}


CHANNELS = [
    ChannelConfig(range_m=800.0, latency_s=0.02, jitter_s=0.01, rate_hz=2, loss=BernoulliLoss(p=0.1)),
    ChannelConfig(range_m=350.0, latency_s=0.3, jitter_s=1.4, loss=BernoulliLoss(p=0.3), max_in_flight=7),
    ChannelConfig(range_m=500.0, latency_s=0.0, jitter_s=0.0, loss=BernoulliLoss(p=0.0)),
]
PARAMS = [
    WaveDamping.Params(),
    WaveDamping.Params(free_above_mps=None, horizon_m=260.0, cell_m=50.0, stale_after_s=0.6, release_after_m=40.0,
                       rsu_period_s=1.0, sensor_noise_mps=2.0, u_min_mps=0.0, a_max_mps2=2.5),
    WaveDamping.Params(cell_m=30.0, zone_before_m=400.0, free_above_mps=10.0, stale_after_s=3.0),
]


@pytest.mark.parametrize("case", range(len(CHANNELS)))
def test_compiled_tick_is_the_python_tick(case: int) -> None:
    chan, params = CHANNELS[case], PARAMS[case]
    rng = np.random.default_rng(300 + case)
    n_cmd = n_fallback = n_release = 0
    for drive_no in range(12):
        duration = 60.0 if drive_no % 3 else 20.0  # copies past the run's end dropped
        drive = _Drive(rng)
        ref, got = (_controller(params, chan, duration, drive_no, False),
                    _controller(params, chan, duration, drive_no, True))
        for tick in range(120):
            t = 0.5 * tick
            s_ref = drive.state()
            s_got = {k: v.copy() for k, v in s_ref.items()}
            ref._communicate(t, s_ref)
            cmds_ref = ref._decide(t, s_ref)
            cmds_got = got._tick_compiled(t, s_got)
            assert cmds_got == cmds_ref, (drive_no, tick)
            assert got.events.events == ref.events.events
            assert (got.fallbacks, got.commands_sent, got.controlled) == (ref.fallbacks, ref.commands_sent, ref.controlled)
            assert repr(got._channel_stats()) == repr(ref._channel_stats())  # NaN: no ratio yet, no AoI
            assert got.sensor_rng.bit_generator.state == ref.sensor_rng.bit_generator.state
            assert got.channel._rng.bit_generator.state == ref.channel._rng.bit_generator.state
            for vid, msg in ref.latest.items():  # the messages received: time and cells
                q = got._latest_row[got.channel.index[vid]]
                assert got._msg_t[q] == msg.t_sent_s
                assert np.array_equal(got._msg_cells[q], msg.cell_speed_mps, equal_nan=True)
            assert int((got._latest_row >= 0).sum()) == len(ref.latest)
            n_cmd += sum(type(c).__name__ == "SetSpeed" for c in cmds_ref)
            n_release += sum(type(c).__name__ == "Release" for c in cmds_ref)
            drive.step()
        n_fallback += ref.fallbacks
        st = ref._channel_stats()
        assert st.sent > 0
    assert n_cmd > 100 and n_release > 50 and n_fallback > 10, (n_cmd, n_release, n_fallback)


def test_the_compiled_tick_is_not_used_where_it_does_not_apply() -> None:
    chan = CHANNELS[0]
    for params in (WaveDamping.Params(yield_stop_m=20.0), WaveDamping.Params(gap_headway_s=1.5),
                   WaveDamping.Params(horizon_m=400.0)):
        c = WaveDamping("wave", params, SimpleNamespace(channels={"v2x": chan}))
        c.period = 0.5
        c.setup(_ctx(60.0, 0))
        assert not c.compiled


@pytest.mark.parametrize("params", [WaveDamping.Params(a_max_mps2=40.0, b_comfort_mps2=40.0),
                                    WaveDamping.Params(free_above_mps=None, horizon_m=240.0, cell_m=45.0),
                                    WaveDamping.Params(u_min_mps=0.0, free_above_mps=12.0, a_max_mps2=9.0)])
def test_law_is_wave_dampings_speed(params: WaveDamping.Params) -> None:
    """``wave_kernel.law_speed`` against ``WaveDamping._speed`` (the plain law) on random messages (NaN
    cells, free cells), positions on the cells' edges (a centre, a centre - horizon) and between, leaders
    near and far, no leader."""
    from corridor.controllers.merging.wave_components import RoadAhead

    c = _controller(params, CHANNELS[0], 60.0, 0, True)
    rng = np.random.default_rng(4)
    edges = np.concatenate([c.cells, c.cells - params.horizon_m])
    n_free = 0
    for _ in range(3000):
        cells = _values(rng, len(c.cells), 0.0, 32.0)
        cells[rng.random(len(cells)) < 0.25] = np.nan
        cells[rng.random(len(cells)) < 0.1] = params.free_above_mps or 18.0  # on the free test's edge
        msg = RoadAhead(0.0, c.cells, cells, np.empty(0))
        for _ in range(6):
            x = float(rng.choice(edges)) if rng.random() < 0.5 else float(rng.uniform(c.cells[0] - 200.0, END_X))
            v, v_lead = float(_values(rng, 1, 0.0, 32.0)[0]), float(_values(rng, 1, 0.0, 32.0)[0])
            gap = math.inf if rng.random() < 0.2 else float(_values(rng, 1, -2.0, 80.0)[0])
            ref = c._speed(0.0, msg, x, v, gap, v_lead if math.isfinite(gap) else params.u_max_mps)
            got = wk.law_speed(c._wave_cfg, c.cells, cells, x, v, gap, v_lead if math.isfinite(gap) else params.u_max_mps)
            assert got == ref, (x, v, gap, v_lead, cells)
            n_free += not math.isfinite(gap)
    assert n_free > 1000


def _gap_controller(params: Any, chan: ChannelConfig, duration: float, seed: int, compiled: bool) -> Any:
    from corridor.controllers.merging.gap_components import GapMerging

    c = GapMerging("gaps", params, SimpleNamespace(channels={"v2x": chan}))
    c.period = 0.5
    c.setup(_ctx(duration, seed))
    assert c.compiled and c._fused
    c.compiled = compiled
    return c


@pytest.mark.parametrize("case", range(len(CHANNELS)))
def test_compiled_tick_of_merge_gaps_is_its_python_tick(case: int) -> None:
    """``v2x_merge_gaps`` on the compiled tick (its RSU's message measured in Python, the copies, the
    delivery and the highway law compiled, the partners' caps and the ramp vehicles in Python) against
    ``_communicate`` + ``_decide``."""
    from corridor.controllers.merging.gap_components import GapMerging

    chan = CHANNELS[case]
    params = GapMerging.Params(**{k: v for k, v in PARAMS[case].model_dump().items() if k not in ("stopper", "safety")})
    rng = np.random.default_rng(400 + case)
    n_cmd = n_partner = n_pairs = 0
    for drive_no in range(12):
        duration = 60.0 if drive_no % 3 else 20.0
        # standstills included: the planned crossing speed has a floor (MIN_CROSS_SPEED_MPS) on both paths
        drive = _Drive(rng)
        ref, got = (_gap_controller(params, chan, duration, drive_no, False),
                    _gap_controller(params, chan, duration, drive_no, True))
        for tick in range(120):
            t = 0.5 * tick
            s_ref = drive.state()
            s_got = {k: v.copy() for k, v in s_ref.items()}
            ref._communicate(t, s_ref)
            cmds_ref = ref._decide(t, s_ref)
            cmds_got = got._tick_compiled(t, s_got)
            assert cmds_got == cmds_ref, (drive_no, tick)
            assert got.events.events == ref.events.events
            assert (got.fallbacks, got.commands_sent, got.controlled, got.committed, got.reserved_crossings) == (
                ref.fallbacks, ref.commands_sent, ref.controlled, ref.committed, ref.reserved_crossings)
            assert list(got.pairs.items()) == list(ref.pairs.items()) and got._t_slot == ref._t_slot
            assert repr(got._channel_stats()) == repr(ref._channel_stats())
            for g in ("sensor_rng", "pos_rng"):
                assert getattr(got, g).bit_generator.state == getattr(ref, g).bit_generator.state
            assert got.channel._rng.bit_generator.state == ref.channel._rng.bit_generator.state
            for vid, msg in ref.latest.items():
                mine = got._latest_of(vid)
                assert mine is not None and mine.t_sent_s == msg.t_sent_s and mine.slots == msg.slots
                assert mine.partners == msg.partners and mine.cross_speed_mps == msg.cross_speed_mps
                assert np.array_equal(mine.ramp_eta_s, msg.ramp_eta_s) and mine.yielder == msg.yielder
                assert np.array_equal(mine.cell_speed_mps, msg.cell_speed_mps, equal_nan=True)
                q = got._latest_row[got.channel.index[vid]]
                assert np.array_equal(got._msg_cells[q], msg.cell_speed_mps, equal_nan=True)
            n_cmd += sum(type(c).__name__ == "SetSpeed" for c in cmds_ref)
            n_partner += sum(vid in m.partners for vid, m in ref.latest.items())
            n_pairs += len(ref.pairs)
            drive.step()
    assert n_cmd > 100 and n_partner > 20 and n_pairs > 100, (n_cmd, n_partner, n_pairs)


@pytest.mark.parametrize("compiled", [False, True])
def test_merge_gaps_plans_through_a_standstill_before_the_merge(compiled: bool) -> None:
    """Every cell in the 100 m before the merge at 0 m/s (a standstill, measured without noise): the crossing
    speed is ``MIN_CROSS_SPEED_MPS``, not 0 (its arrival times divided by it), on both paths, which agree."""
    from corridor.controllers.merging.gap_components import GapMerging
    from corridor.controllers.merging.gap_kernel import MIN_CROSS_SPEED_MPS

    params = GapMerging.Params(sensor_noise_mps=0.0, ramp_sensor_noise_m=0.0, partner_min_speed_mps=0.5)
    ref, got = (_gap_controller(params, CHANNELS[2], 60.0, 0, False),
                _gap_controller(params, CHANNELS[2], 60.0, 0, compiled))
    # id: front, speed, length, connected, ramp role, on ramp (stopped at the merge; a partner upstream; a
    # connected ramp vehicle on its run)
    veh = {"h0": (MERGE_X - 60.0, 0.0, 5.0, False, False, False), "h1": (MERGE_X - 20.0, 0.0, 5.0, True, False, False),
           "h2": (MERGE_X - 300.0, 25.0, 5.0, True, False, False), "r0": (MERGE_X - 150.0, 10.0, 5.0, True, True, True)}
    n_cmd = 0
    for tick in range(6):
        t = 0.5 * tick
        a = np.array([v[:3] for v in veh.values()], dtype=float)
        b = np.array([v[3:] for v in veh.values()], dtype=bool)
        s_ref = {"ids": list(veh), "front": a[:, 0] + (tick * 0.5 * a[:, 1]), "speed": a[:, 1].copy(),
                 "length": a[:, 2].copy(), "on_ramp": b[:, 2].copy(), "ramp": b[:, 1].copy(),
                 "connected": b[:, 0].copy(), "pos": np.column_stack([a[:, 0] - 2.0, np.zeros((len(veh), 2))])}
        s_got = {k: v.copy() for k, v in s_ref.items()}
        cmds_got = got._tick_compiled(t, s_got) if compiled else (got._communicate(t, s_got), got._decide(t, s_got))[1]
        ref._communicate(t, s_ref)
        cmds_ref = ref._decide(t, s_ref)
        assert cmds_got == cmds_ref
        msg = got._latest_of("r0")
        assert msg is not None and msg.cross_speed_mps == MIN_CROSS_SPEED_MPS
        assert np.all(msg.cell_speed_mps[got._near_cells][np.isfinite(msg.cell_speed_mps[got._near_cells])] == 0.0)
        n_cmd += any(c.vid == "r0" for c in cmds_got if type(c).__name__ == "SetSpeed")
    assert n_cmd == 6 and "r0" in got.pairs


def test_ramp_command_is_the_python_ramp_command() -> None:
    """``GapMerging._ramp_command_c`` (``gap_kernel.ramp_command``) against ``_ramp_command``, bit for bit, on
    random vehicles and messages: the speed, the mode, the committed set, the counter and the events (with a
    slot and without, committed or not, with and without a virtual and a physical leader, at speeds where
    ``v ** 2`` and ``v * v`` differ)."""
    from corridor.controllers.merging.gap_components import GapMerging, MergePlan, Slot

    rng = np.random.default_rng(15)
    n_commit = n_uncommit = n_wait = n_slot = 0
    for params in (GapMerging.Params(), GapMerging.Params(commit_m=10.0, wait_speed_mps=2.0, plan_accel_mps2=0.4,
                                                          b_comfort_mps2=3.0, a_max_mps2=2.5)):
        ref, got = (_gap_controller(params, CHANNELS[2], 60.0, 0, False),
                    _gap_controller(params, CHANNELS[2], 60.0, 0, True))
        for i in range(40000):
            t = float(rng.uniform(0.0, 50.0))
            x = float(rng.uniform(MERGE_X - 300.0, MERGE_X + 5.0))
            v = float(rng.choice([0.0, rng.uniform(0.0, 20.0), 11.300000000000001]))
            lead = None if rng.random() < 0.3 else (x + float(rng.uniform(-20.0, 60.0)), float(rng.uniform(0.0, 25.0)),
                                                    float(rng.choice([4.5, 5.0])))
            slot = Slot(t + float(rng.uniform(-2.0, 40.0)), 0.0, lead,
                        (x - float(rng.uniform(-10.0, 80.0)), float(rng.uniform(0.0, 25.0)), 5.0),
                        (x, v, float(rng.choice([4.5, 5.0]))))
            vid = f"r{i % 7}"
            msg = MergePlan(t - float(rng.uniform(0.0, 1.0)), np.zeros(0), np.zeros(0), np.zeros(0), None,
                            {vid: slot} if rng.random() < 0.7 else {}, {}, float(rng.uniform(1.0, 15.0)))
            leader = (math.inf, 0.0) if rng.random() < 0.4 else (float(rng.uniform(-2.0, 60.0)), float(rng.uniform(0.0, 20.0)))
            if rng.random() < 0.3:
                ref.committed.add(vid)
                got.committed.add(vid)
            before = vid in ref.committed
            out_ref = ref._ramp_command(t, msg, vid, x, v, leader)
            out_got = got._ramp_command_c(t, msg, vid, x, v, leader)
            assert out_got == out_ref, (i, t, x, v, slot, msg.cross_speed_mps, leader, before)
            assert got.committed == ref.committed and got.reserved_crossings == ref.reserved_crossings
            n_commit += (not before) and vid in ref.committed
            n_uncommit += before and vid not in ref.committed
            n_wait += vid not in msg.slots and not before
            n_slot += vid in msg.slots and not before
        assert got.events.events == ref.events.events
    assert min(n_commit, n_uncommit) > 500 and min(n_wait, n_slot) > 5000, (n_commit, n_uncommit, n_wait, n_slot)


def test_partner_cap_is_the_python_partner_cap() -> None:
    """``gap_kernel.partner_cap`` (the compiled tick's ``_capped``) against ``GapMerging._partner_cap``, bit for
    bit, on random partners and slots (restart gaps, slots due or past, ramp vehicles behind, slow or on their run)."""
    from corridor.controllers.merging.gap_components import GapMerging, MergePlan, Slot
    from corridor.controllers.merging.gap_kernel import partner_cap

    rng = np.random.default_rng(16)
    n_safe = n_floor = 0
    for params in (GapMerging.Params(), GapMerging.Params(partner_min_speed_mps=8.0, restart_partner_speed_mps=3.0,
                                                          open_time_gap_s=1.0, wait_speed_mps=2.0)):
        c = _gap_controller(params, CHANNELS[2], 60.0, 0, True)
        for _ in range(60000):
            t = float(rng.uniform(0.0, 50.0))
            x, v = float(rng.uniform(MERGE_X - 400.0, MERGE_X + 5.0)), float(rng.uniform(0.0, 30.0))
            t_ramp = t + float(rng.uniform(-3.0, 30.0))
            ramp = (x + float(rng.uniform(-20.0, 80.0)), float(rng.choice([rng.uniform(0.0, 20.0), params.wait_speed_mps])),
                    float(rng.choice([4.5, 5.0])))
            slot = Slot(t_ramp, t_ramp + float(rng.choice([params.open_time_gap_s, 5.0, rng.uniform(0.0, 6.0)])), None,
                        (x, v, 5.0), ramp)
            msg = MergePlan(t - float(rng.uniform(0.0, 1.0)), np.zeros(0), np.zeros(0), np.zeros(0), None,
                            {"r": slot}, {"p": "r"}, 15.0)
            v_cmd = float(rng.uniform(0.0, 32.0))
            ref = c._partner_cap(t, msg, x, v, "p", v_cmd)
            got = partner_cap(c._ramp_cfg, t, msg.t_sent_s, slot.t_partner_s, slot.t_ramp_s, *ramp, x, v, v_cmd)
            assert got == ref, (t, x, v, slot, v_cmd)
            n_safe += ref < v_cmd
            n_floor += ref == 0.0
    assert n_safe > 20000 and n_floor > 0, (n_safe, n_floor)
