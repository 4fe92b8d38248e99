"""ALINEA against its formula r(k) = clip(r(k-1) + K_R (o_set - o)), and its queue override."""

from __future__ import annotations

import pytest

from corridor.controllers.ramp_metering.alinea import Alinea, AlineaConfig, occupancy_from_density

CFG = AlineaConfig(gain_vph_per_pct=70.0, setpoint_pct=20.0, rate_min_vph=200.0, rate_max_vph=1800.0)


def test_integral_law_and_clipping() -> None:
    m = Alinea(CFG)
    m.reset(rate_vph=1000.0)
    assert m.step(25.0) == pytest.approx(1000.0 + 70.0 * (20.0 - 25.0))  # 650
    assert m.step(18.0) == pytest.approx(650.0 + 70.0 * 2.0)  # 790
    assert m.step(100.0) == pytest.approx(200.0)  # 790 - 5600 -> r_min
    assert m.step(0.0) == pytest.approx(200.0 + 70.0 * 20.0)  # integrates from the clipped rate: 1600
    assert m.step(0.0) == pytest.approx(1800.0)  # 3000 -> r_max


def test_reset_opens_the_meter() -> None:
    m = Alinea(CFG)
    m.step(60.0)
    m.reset()
    assert m.rate_vph == CFG.rate_max_vph
    assert m.step(20.0) == pytest.approx(1800.0)  # at the set point the rate is held


def test_queue_override_raises_rate() -> None:
    cfg = AlineaConfig(storage_veh=50.0, override_frac=0.8, period_s=60.0, rate_min_vph=200.0)
    m = Alinea(cfg)
    m.reset(rate_vph=300.0)
    # occupancy far above set point -> ALINEA alone gives 200; queue 45 > target 40:
    # r_q = 900 + (45 - 40)/(60/3600) = 1200
    assert m.step(80.0, queue_veh=45.0, demand_vph=900.0) == pytest.approx(1200.0)
    assert m.override_active
    # below the target the override is silent
    m.reset(rate_vph=300.0)
    assert m.step(80.0, queue_veh=30.0, demand_vph=900.0) == pytest.approx(200.0)
    assert not m.override_active
    # without a demand estimate the meter opens fully
    m.reset(rate_vph=300.0)
    assert m.step(80.0, queue_veh=45.0) == pytest.approx(cfg.rate_max_vph)


def test_queue_stays_under_storage_with_high_occupancy() -> None:
    cfg = AlineaConfig(storage_veh=60.0, override_frac=0.8, period_s=60.0)
    m = Alinea(cfg)
    queue, demand = 0.0, 1200.0  # [veh], [veh/h]
    peak = 0.0
    for _ in range(60):
        rate = m.step(45.0, queue_veh=queue, demand_vph=demand)  # congested mainline keeps pushing down
        queue = max(queue + (demand - rate) * cfg.period_s / 3600.0, 0.0)
        peak = max(peak, queue)
    assert peak <= cfg.storage_veh
    assert peak >= 0.8 * cfg.storage_veh - 1e-9  # the meter did hold traffic back up to the target


def test_occupancy_from_density() -> None:
    assert occupancy_from_density(33.5, 7.0) == pytest.approx(23.45)


def test_invalid_config() -> None:
    with pytest.raises(ValueError):
        AlineaConfig(rate_min_vph=2000.0, rate_max_vph=1000.0)
