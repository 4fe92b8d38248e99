"""scenarios/hegyi_benchmark.yaml: the Hegyi benchmark as a scenario on the pure METANET backend."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.ramp_metering.hegyi import SYM_METANET_NO_CONTROL_TTS
from corridor.run import simulate
from corridor.scenario import load
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "hegyi_benchmark.yaml"


def test_no_control_scenario_matches_independent_implementation() -> None:
    """The engine-driven backend integrates exactly like sym-metanet (1433.788 veh h) and reports
    the published figure beside it."""
    sc, _ = load(SCENARIO)
    metrics, _, _ = simulate(sc, seed=0)
    assert metrics["tts_vh"] == pytest.approx(SYM_METANET_NO_CONTROL_TTS, rel=1e-5)
    assert metrics["tts_published_vh"] == 1554.0
    assert metrics["tts_rel_diff_published"] == pytest.approx((metrics["tts_vh"] - 1554.0) / 1554.0)


def test_alinea_lowers_tts_and_mpc_respects_its_bounds() -> None:
    sc, _ = load(SCENARIO, ["controllers.ramp={type: metanet_alinea}"])
    alinea, _, _ = simulate(sc, seed=0)
    assert alinea["tts_vh"] < SYM_METANET_NO_CONTROL_TTS - 10.0  # metering relieves the merge
    sc, _ = load(SCENARIO, ["controllers.ramp={type: metanet_mpc, params: {horizon_ctrl_steps: 3}}",
                            "duration=1200"])
    mpc, ctx, _ = simulate(sc, seed=0)
    assert mpc["mpc_solves"] == 20 and mpc["mpc_fallbacks"] == 0
    backend = ctx.get("freeway")
    assert np.all(backend.u[:1] >= 0.0) and np.all(backend.u[:1] <= 1.0)
    assert mpc["queue_max_over_storage"] <= 1.02  # soft 100-veh limit on the ramp queue
