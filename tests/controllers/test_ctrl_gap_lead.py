"""The gap made from ahead (``v2x_merge_gaps`` with ``lead_close_up``): a connected highway vehicle ahead of a
slot closes up to its own leader, the ramp vehicle crosses ``lead_ramp_gap_s`` behind it and a human follower
qualifies at its own speed; the partner-slows pairing is the fallback.  The planner on a constructed stream
(Python and compiled), the leader's law on a point mass, and both code paths on a short SUMO run."""

from __future__ import annotations

import math
import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.controllers.merging.gap_components import GapMerging
from corridor.controllers.merging.gap_kernel import HAVE_C_POW, cfg_array
from corridor.controllers.merging.safety_layer import SafetyParams
from corridor.events import EventLog
from tests.conftest import SCENARIOS

MERGE_X, CROSS_X = 600.0, 700.0
COS_RAMP = math.cos(math.radians(12.0))
QUIET = {"ramp_sensor_noise_m": 0.0, "sensor_noise_mps": 0.0}


def _controller(params: GapMerging.Params) -> GapMerging:
    c = GapMerging("gaps", params, SimpleNamespace(channels={}))
    c.merge_x, c.cross_x, c.cos_ramp = MERGE_X, CROSS_X, COS_RAMP
    c.pos_rng, c.sensor_rng = np.random.default_rng(0), np.random.default_rng(1)
    c.events = EventLog()
    c._plan_cfg = cfg_array(params, c.merge_x, c.cross_x, c.cos_ramp)
    c.period, c.safety = 0.5, SafetyParams(reaction_s=0.5, b_ego_mps2=9.0, b_lead_mps2=9.0, s0_m=2.0)
    return c


def _stream() -> dict[str, Any]:
    """A single-lane stream at 25 m/s (1.8 s headways, one of 2.4 s) and a connected ramp vehicle 130 m before
    the junction at 15 m/s (it can be there in 8.7 s).  ``L`` (connected) is 265 m from the junction (10.6 s),
    its leader ``L2`` 1.8 s ahead, its follower ``F`` (human) 2.4 s behind it."""
    hw = [("A", 470.0, False), ("B", 425.0, False), ("L2", 380.0, False), ("L", 335.0, True), ("F", 275.0, False),
          ("G", 230.0, False), ("H", 185.0, False)]
    veh = [(vid, x, 25.0, conn, False) for vid, x, conn in hw]
    veh.append(("r", MERGE_X - 130.0 * COS_RAMP, 15.0, True, True))
    return {"ids": [v[0] for v in veh], "front": np.array([v[1] for v in veh]), "speed": np.array([v[2] for v in veh]),
            "length": np.full(len(veh), 5.0), "connected": np.array([v[3] for v in veh]),
            "ramp": np.array([v[4] for v in veh]), "on_ramp": np.array([v[4] for v in veh])}


def _plan(params: GapMerging.Params, compiled: bool) -> tuple[GapMerging, dict[str, Any]]:
    c = _controller(params)
    slots = c._slots(0.0, _stream(), 15.0) if compiled else c._slots_py(0.0, _stream(), 15.0)
    return c, slots


@pytest.mark.parametrize("compiled", [False, True] if HAVE_C_POW else [False])
def test_a_connected_leader_gets_a_slot_behind_it_with_a_human_follower(compiled: bool) -> None:
    """With the option the ramp vehicle is put behind the connected ``L``, before the human ``F``, who arrives
    2.4 s after ``L`` at its own speed: ``L``'s planned arrival is 1.0 s after ``L2``'s (9.8 s, not 10.6 s),
    the slot 1.0 s later (10.8 s), ``F`` 2.2 s after it (>= open_time_gap_s 2.0 s).  Without it ``F`` would need
    3.5 s after ``L`` (ramp_time_gap_s + open_time_gap_s): ``L`` is made a partner and slows instead."""
    c, slots = _plan(GapMerging.Params(**QUIET, lead_close_up=True), compiled)
    assert c.pairs == {"r": "F"} and c.leaders == {"r": "L"}
    slot = slots["r"]
    assert slot.t_ramp_s == pytest.approx((MERGE_X - 380.0) / 25.0 + 1.0 + 1.0)
    assert slot.lead is not None and slot.lead[0] == 335.0  # the virtual leader: L
    assert slot.t_partner_s - slot.t_ramp_s == 2.0 and (MERGE_X - 275.0) / 25.0 >= slot.t_partner_s  # F as it drives
    off, _ = _plan(GapMerging.Params(**QUIET), compiled)
    assert off.pairs == {"r": "L"} and off.leaders == {}  # the partner-slows pairing


@pytest.mark.parametrize("compiled", [False, True] if HAVE_C_POW else [False])
def test_without_a_connected_leader_in_reach_the_partner_slows(compiled: bool) -> None:
    """No slot behind a connected leader fits (``F`` 1.8 s behind ``L``: 0.8 s short): the fallback pairs as before."""
    params = GapMerging.Params(**QUIET, lead_close_up=True)
    c = _controller(params)
    s = _stream()
    s["front"][s["ids"].index("F")] = 290.0  # 1.8 s behind L
    slots = c._slots(0.0, s, 15.0) if compiled else c._slots_py(0.0, s, 15.0)
    ref = _controller(GapMerging.Params(**QUIET))
    ref_slots = ref._slots_py(0.0, s, 15.0)
    assert c.pairs == ref.pairs == {"r": "L"} and c.leaders == {}
    assert slots["r"].t_partner_s == ref_slots["r"].t_partner_s


def test_the_leader_closes_up_to_its_time_gap_and_no_faster_than_the_limit() -> None:
    """A point mass under the leader's law behind a vehicle at 25 m/s, from a 1.8 s time gap: it settles at
    s0 + lead_time_gap_s x v (27 m), never closer than 0.8 s, and on an open road never above u_max_mps."""
    c = _controller(GapMerging.Params(lead_close_up=True))
    x_l, x, v = 50.0, 0.0, 25.0
    low = math.inf
    for _ in range(240):  # 120 s
        gap = x_l - 5.0 - x
        v_new = c._lead_speed(v, gap, 25.0)
        x += 0.5 * (v + v_new) * 0.5
        v = v_new
        x_l += 25.0 * 0.5
        low = min(low, (x_l - 5.0 - x) / 25.0)
    assert x_l - 5.0 - x == pytest.approx(2.0 + 1.0 * 25.0, abs=0.5)
    assert low >= 0.8, low
    speeds = [20.0]
    for _ in range(60):
        speeds.append(c._lead_speed(speeds[-1], math.inf, 30.0))
    assert max(speeds) <= c.gp.u_max_mps and speeds[-1] == pytest.approx(c.gp.u_max_mps)
    assert max(np.diff(speeds)) <= c.gp.a_max_mps2 * 0.5 + 1e-12


def _run(duration_s: float, seed: int, compiled: bool) -> tuple[dict, list, int]:
    """``cal_all10_lead`` for ``duration_s`` on the compiled tick or on the Python one: the run's metrics, its
    controller's events and the ticks x leaders commanded."""
    from corridor.run import build
    from corridor.scenario import apply_overrides, load, validate

    sc, raw = load(SCENARIOS / "flow_merge.yaml", [f"duration={duration_s}"])
    sim = build(validate(apply_overrides(raw, sc.sweep["cal_all10_lead"]), "cal_all10_lead"), seed,
                Path(tempfile.mkdtemp()))
    ctx = sim.ctx
    for c in ctx.components.values():
        c.setup(ctx)
    ctrl = ctx.components["wave"]
    assert ctrl.gp.lead_close_up and ctrl.compiled
    ctrl.compiled = compiled
    n_lead = 0
    for _ in range(round(duration_s / ctx.dt)):
        sim.step()
        n_lead += len({v for v in ctrl.leaders.values()} & ctrl.controlled)
    metrics: dict = {}
    for c in ctx.components.values():
        metrics.update(c.finish(ctx))
        c.close()
    return metrics, [(e.t, e.kind, e.message) for e in ctrl.events.events], n_lead


def _nan_as_none(m: dict) -> dict:
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in m.items()}


@pytest.mark.skipif(not HAVE_C_POW, reason="the compiled tick needs glibc's powf64")
def test_the_compiled_and_the_python_tick_run_alike_with_leaders() -> None:
    """``cal_all10_lead`` (seed 0, 300 s) on the compiled tick and on ``_communicate`` + ``_decide``: the same
    metrics and events; leaders are commanded; no collision."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:  # libsumo: one per process
        m_c, ev_c, lead_c = pool.submit(_run, 300.0, 0, True).result()
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        m_p, ev_p, lead_p = pool.submit(_run, 300.0, 0, False).result()
    assert _nan_as_none(m_c) == _nan_as_none(m_p)
    assert ev_c == ev_p
    assert lead_c == lead_p and lead_c > 20, lead_c
    assert m_c["collisions"] == 0 and m_c["v2x_reserved_crossings"] >= 2
