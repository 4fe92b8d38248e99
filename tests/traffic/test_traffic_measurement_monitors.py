"""Measurement belongs to monitors: the signals specs and reports judge exist whatever controls the
world (a baseline controller, or none at all)."""

from __future__ import annotations

import math

import numpy as np

from corridor.run import simulate
from corridor.scenario import load
from tests.conftest import SCENARIOS

SPEC_SIGNALS = ("gap_lead", "ahead_lead", "lat_lead", "lat_onc", "gap_onc", "lane_offset", "clearance")


def test_overtaking_spec_signals_without_the_controller() -> None:
    """controller ``none``: the ego coasts behind the lead; the monitor still measures every spec input."""
    sc, _ = load(SCENARIOS / "overtaking.yaml", ["controllers.overtaking.type=none", "duration=66"])
    metrics, ctx, _ = simulate(sc, seed=0)
    for name in SPEC_SIGNALS:
        t, v = ctx.signals.get(name)
        assert len(t) >= 25 and np.isfinite(v).all(), name  # every 0.2 s from the ego's entry at 60 s
        assert t[0] >= 60.0 - 1e-9
    _, lane = ctx.signals.get("lane_offset")
    assert np.abs(lane).max() < 0.5  # nobody steers: it stays in its lane
    for spec in ("safety", "completion"):
        assert isinstance(metrics[f"spec.{spec}.satisfied"], bool)
        assert math.isfinite(metrics[f"spec.{spec}.space"])
    assert metrics["spec.completion.satisfied"] is False  # no pass without a controller
    assert "replans" not in metrics and "min_gap_lead_m" in metrics


def test_ramp_meter_rates_recorded_without_control() -> None:
    """``ramp_none`` (meters off) and no controller at all (the network's own meter program)."""
    for ctrl, expected in (("ramp_none", 1800.0), ("none", 900.0)):
        sc, _ = load(SCENARIOS / "ramp_metering.yaml", [f"controllers.ramps.type={ctrl}", "duration=130"])
        _, ctx, _ = simulate(sc, seed=0)
        rates = sorted(n for n in ctx.signals.names() if n.startswith("rate_"))
        assert len(rates) == 16, (ctrl, rates)  # 8 interchanges x 2 directions
        for n in rates:
            t, v = ctx.signals.get(n)
            assert list(t) == [0.0, 60.0, 120.0] and (v == expected).all(), (ctrl, n, v)
