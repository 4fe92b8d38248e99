"""The gap made from ahead, second iteration (``v2x_merge_gaps`` with ``lead_close_up`` and ``lead_hold``): a slot
behind a connected leader holds once given (the follower's fit checked at pairing, with a margin for the RSU's
noise), every connected highway vehicle in the pair zone closes up while a connected ramp vehicle comes, and no
partner slows.  The planner on a constructed stream, and both tick paths on a short SUMO run."""

from __future__ import annotations

import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.controllers.merging.gap_components import GapMerging
from corridor.controllers.merging.gap_kernel import HAVE_C_POW
from tests.conftest import SCENARIOS
from tests.controllers.test_ctrl_gap_lead import COS_RAMP, MERGE_X, QUIET, _controller, _nan_as_none, _stream

ZERO = SimpleNamespace(normal=lambda loc, scale, n: np.zeros(n))  # exact measurements, the noise's sigma kept
HOLD = {"lead_close_up": True, "lead_hold": True}


def _exact(params: GapMerging.Params) -> GapMerging:
    """A controller whose RSU measures exactly (so the margin for its noise, from the sigmas, is the only effect)."""
    c = _controller(params)
    c.pos_rng, c.sensor_rng = ZERO, ZERO
    return c


def _moved(s: dict[str, Any], dt: float, f_x: float) -> dict[str, Any]:
    """``s`` ``dt`` later (the highway at 25 m/s, the ramp vehicle at 15 m/s along the ramp), ``F`` measured at
    ``f_x``."""
    s = {k: v.copy() if isinstance(v, np.ndarray) else list(v) for k, v in s.items()}
    s["front"][~s["on_ramp"]] += 25.0 * dt
    s["front"][s["on_ramp"]] += 15.0 * dt * COS_RAMP
    s["front"][s["ids"].index("F")] = f_x
    return s


PATHS = [False, True] if HAVE_C_POW else [False]


def _slots(c: GapMerging, t: float, s: dict[str, Any], compiled: bool) -> dict[str, Any]:
    return c._slots(t, s, 15.0) if compiled else c._slots_py(t, s, 15.0)


@pytest.mark.parametrize("compiled", PATHS)
def test_the_follower_gap_is_the_calibrated_humans_and_the_noise_margin_refuses_a_marginal_fit(compiled: bool) -> None:
    """The follower gap at the crossing speed 15 m/s: 1.2 s + 7 m / 15 m/s.  ``F`` (human, 13.0 s) is 2.2 s after
    the slot behind ``L`` (10.8 s): enough for the gap alone (1.67 s), not with 2 sigma of the RSU's arrival-time
    error of ``F`` and ``L`` (0.68 s); with ``lead_noise_k`` 0 it is paired."""
    c = _exact(GapMerging.Params(**HOLD))
    c._v_cross = 15.0
    assert c._follow_gap(15.0, 130.0) == pytest.approx(1.2 + 7.0 / 15.0)
    slots = _slots(c, 0.0, _stream(), compiled)
    assert slots == {} and c.pairs == {}
    k0 = _exact(GapMerging.Params(**HOLD, lead_noise_k=0.0))
    _slots(k0, 0.0, _stream(), compiled)
    assert k0.pairs == {"r": "F"} and k0.leaders == {"r": "L"} and k0._held == {"r"}


@pytest.mark.parametrize("compiled", PATHS)
def test_a_held_slot_survives_a_rebroadcast_with_the_noisy_follower(compiled: bool) -> None:
    """``F`` 2.8 s behind ``L`` is paired with the margin (the ramp vehicle 150 m before the junction); half a second later the RSU measures ``F`` 35 m further
    on (predicted 1.4 s earlier, 0.8 s before the slot plus its gap): the held slot stays, at the same time,
    behind the same leader.  Without ``lead_hold`` the same pair is dropped at that broadcast."""
    s0 = _stream()
    s0["front"][s0["ids"].index("F")] = 265.0
    s0["front"][s0["ids"].index("r")] = MERGE_X - 150.0 * COS_RAMP  # not yet on its run (no commit before 135 m)
    s1 = _moved(s0, 0.5, 265.0 + 12.5 + 35.0)
    c = _exact(GapMerging.Params(**HOLD))
    first = _slots(c, 0.0, s0, compiled)
    assert c.pairs == {"r": "F"} and c._held == {"r"}
    again = _slots(c, 0.5, s1, compiled)
    assert c.pairs == {"r": "F"} and c.leaders == {"r": "L"} and c._held == {"r"}
    assert again["r"].t_ramp_s == first["r"].t_ramp_s
    assert again["r"].lead is not None and again["r"].lead[0] == 335.0 + 12.5  # the leader's state re-sent
    old = _exact(GapMerging.Params(lead_close_up=True))
    _slots(old, 0.0, s0, compiled)
    assert old.pairs == {"r": "F"}
    _slots(old, 0.5, s1, compiled)
    assert "r" not in old.pairs


@pytest.mark.parametrize("compiled", PATHS)
def test_no_partner_slows(compiled: bool) -> None:
    """``F`` 1.8 s behind ``L``: no natural gap fits anywhere, so with ``lead_hold`` nobody is paired; the first
    iteration (and the option off) made ``L`` a partner that slows."""
    s = _stream()
    s["front"][s["ids"].index("F")] = 290.0
    c = _controller(GapMerging.Params(**QUIET, **HOLD))
    _slots(c, 0.0, s, compiled)
    assert c.pairs == {}
    old = _controller(GapMerging.Params(**QUIET, lead_close_up=True))
    _slots(old, 0.0, s, compiled)
    assert old.pairs == {"r": "L"}
    assert not c._fits_at(True, 335.0, 10.6, 0.0, 10.3, 1.67)  # a connected follower at its own speed


def test_every_connected_highway_vehicle_in_the_pair_zone_closes_up_while_a_ramp_vehicle_comes() -> None:
    c = _controller(GapMerging.Params(**QUIET, **HOLD, pair_zone_m=300.0))
    s = _stream()
    s["connected"][s["ids"].index("B")] = True
    assert c._closing(s) == ["B", "L"]  # connected and in the 300 m before the junction (B at 425 m, L at 335 m)
    s["connected"][s["ids"].index("r")] = False
    assert c._closing(s) == []  # no connected ramp vehicle: nobody closes up


def _run(duration_s: float, seed: int, compiled: bool, py_plan: bool = False) -> tuple[dict, list, int]:
    """``cal_all10_lead2`` for ``duration_s`` on the compiled tick or on the Python one (``py_plan``: the RSU's
    planning in Python, ``_slots_py``, not ``gap_kernel.plan_slots``): the run's metrics, its controller's events
    and the ticks x closing vehicles commanded."""
    from corridor.run import build
    from corridor.scenario import apply_overrides, load, validate

    sc, raw = load(SCENARIOS / "flow_merge.yaml", [f"duration={duration_s}"])
    sim = build(validate(apply_overrides(raw, sc.sweep["cal_all10_lead2"]), "cal_all10_lead2"), seed,
                Path(tempfile.mkdtemp()))
    ctx = sim.ctx
    for c in ctx.components.values():
        c.setup(ctx)
    ctrl = ctx.components["wave"]
    assert ctrl.gp.lead_close_up and ctrl.gp.lead_hold and ctrl.compiled
    ctrl.compiled = compiled
    if py_plan:
        ctrl._slots = ctrl._slots_py
    n_close = 0
    for _ in range(round(duration_s / ctx.dt)):
        sim.step()
        n_close += len(set(ctrl._closers) & ctrl.controlled)
    metrics: dict = {}
    for c in ctx.components.values():
        metrics.update(c.finish(ctx))
        c.close()
    return metrics, [(e.t, e.kind, e.message) for e in ctrl.events.events], n_close


@pytest.mark.skipif(not HAVE_C_POW, reason="the compiled tick needs glibc's powf64")
def test_the_compiled_and_the_python_tick_run_alike_with_closers() -> None:
    """``cal_all10_lead2`` (seed 0, 300 s) on the compiled tick and on ``_communicate`` + ``_decide``, and with the
    RSU's planning compiled and in Python: the same metrics and events; the closing vehicles are commanded; no
    collision."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:  # libsumo: one per process
        m_c, ev_c, n_c = pool.submit(_run, 300.0, 0, True).result()
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        m_p, ev_p, n_p = pool.submit(_run, 300.0, 0, False).result()
    assert _nan_as_none(m_c) == _nan_as_none(m_p)
    assert ev_c == ev_p
    assert n_c == n_p and n_c > 100, n_c
    assert m_c["collisions"] == 0
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:  # the planning in Python: the same run
        m_q, ev_q, n_q = pool.submit(_run, 300.0, 0, True, True).result()
    assert _nan_as_none(m_q) == _nan_as_none(m_c) and ev_q == ev_c and n_q == n_c
