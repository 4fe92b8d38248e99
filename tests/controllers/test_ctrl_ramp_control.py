"""Ramp controllers for the SUMO beltway: ALINEA against its formula, the detector-to-METANET state
mapping, the demand forecast and OD matrix from the scenario, and the MPC's fallback in a short run."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from corridor.controllers.ramp_metering.components import (
    DemandForecast,
    RampAlinea,
    RampObservation,
    RampParams,
    od_matrix,
    setpoint_from_calibration,
)
from corridor.scenario import load
from corridor.traffic.macro.loop_state import (
    estimate_state,
    load_calibration,
    loop_speed_kmh,
)
from corridor.traffic.macro.metanet import MetanetParams
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway
from corridor.traffic.sensing.detectors import RampMeasurement
from corridor.traffic.sumo.road_spec import road_spec
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "ramp_metering.yaml"


def _ramps(n: int, occ: float = 10.0, speed_mps: float = 20.0, queue: float = 0.0) -> dict[str, RampMeasurement]:
    out = {}
    for d in ("ccw", "cw"):
        for k in range(n):
            out[f"{d}{k}"] = RampMeasurement(
                key=f"{d}{k}", direction=d, interchange=k, tls=f"meter_{d}{k}", storage_veh=40.0,
                occupancy_down_pct=occ, occupancy_up_pct=occ, speed_down_mps=speed_mps, speed_up_mps=speed_mps,
                queue_veh=queue)
    return out


def test_alinea_controller_follows_the_formula() -> None:
    p = RampParams(alinea_gain_vph_per_pct=70.0, alinea_setpoint_pct=14.0, rate_min_vph=240.0,
                   open_rate_vph=1800.0, override_frac=0.7)
    ctrl = RampAlinea("ramps", p)
    ctrl.reset(np.random.default_rng(0))
    ramps = _ramps(2, occ=20.0)
    first = ctrl.decide(RampObservation(t=0.0, ramps=ramps))
    assert first["ccw0"] == pytest.approx(1800.0 + 70.0 * (14.0 - 20.0))  # r = r_prev + K (o_set - o)
    second = ctrl.decide(RampObservation(t=60.0, ramps=_ramps(2, occ=10.0)))
    assert second["cw1"] == pytest.approx(first["cw1"] + 70.0 * (14.0 - 10.0))


def test_alinea_setpoint_is_the_calibrated_critical_occupancy(tmp_path: Path) -> None:
    fit = tmp_path / "fit.json"
    fit.write_text('{"v_free_kmh": 90.0, "rho_crit": 40.0, "a": 2.0}')
    p = RampParams(calibration_file=str(fit), vehicle_length_m=5.0)
    assert setpoint_from_calibration(p) == pytest.approx(20.0)  # 40 veh/km x 5 m / 10
    assert setpoint_from_calibration(RampParams(calibration_file=str(fit), alinea_setpoint_pct=12.0)) == 12.0
    ctrl = RampAlinea("ramps", p)
    ctrl.reset(np.random.default_rng(0))
    rate = ctrl.decide(RampObservation(t=0.0, ramps=_ramps(1, occ=25.0)))["ccw0"]
    assert rate == pytest.approx(1800.0 + 70.0 * (20.0 - 25.0))


def test_alinea_setpoint_prefers_the_downstream_loops_fit(tmp_path: Path) -> None:
    fit = tmp_path / "fit.json"
    fit.write_text('{"v_free_kmh": 90.0, "rho_crit": 40.0, "a": 2.0, "alinea_setpoint_pct": 18.5}')
    assert setpoint_from_calibration(RampParams(calibration_file=str(fit))) == pytest.approx(18.5)


def test_loop_speed_is_the_space_mean_speed_in_congestion() -> None:
    # 30 % occupancy with 5 m cars = 60 veh/km/lane; 3000 veh/h over 2 lanes -> q / rho = 25 km/h,
    # below the loops' time-mean 40 km/h (stop-and-go)
    assert loop_speed_kmh(30.0, 3000.0, 40.0 / 3.6, 2, 5.0) == pytest.approx(25.0)
    # light traffic (2 veh/km/lane) or no lane count: the loop speed itself
    assert loop_speed_kmh(1.0, 180.0, 25.0, 2, 5.0) == pytest.approx(90.0)
    assert loop_speed_kmh(30.0, 3000.0, 40.0 / 3.6, None, 5.0) == pytest.approx(40.0)
    # never above the time-mean speed (space-mean <= time-mean)
    assert loop_speed_kmh(10.0, 4000.0, 20.0, 2, 5.0) == pytest.approx(72.0)


def test_alinea_queue_override_keeps_queue_under_storage() -> None:
    ctrl = RampAlinea("ramps", RampParams(override_frac=0.7, control_step_s=60.0, alinea_setpoint_pct=14.0))
    ctrl.reset(np.random.default_rng(0))
    ramps = _ramps(1, occ=40.0, queue=35.0)  # heavy congestion would throttle, but the queue is long
    for m in ramps.values():
        m.demand_vph = 600.0
    rate = ctrl.decide(RampObservation(t=0.0, ramps=ramps))["ccw0"]
    # least rate that brings the queue back to 0.7 x 40 = 28 veh within one 60 s step
    assert rate == pytest.approx(600.0 + (35.0 - 28.0) * 60.0)


def test_state_estimate_maps_occupancy_and_speed() -> None:
    n = 6
    net = beltway(BeltwayLayout(n_interchanges=n, spacing_km=2.5, seg_target_km=1.25, lanes=1),
                  params=MetanetParams(step_h=15.0 / 3600.0))
    m = net.n_seg // (2 * n)
    ramps = _ramps(n, occ=10.0, speed_mps=20.0)
    ramps["cw3"].queue_veh = 7.0
    ramps["ccw3"].occupancy_down_pct = 30.0  # first segment of the ccw link leaving 3 (model dir 0)
    x = estimate_state(net, ramps, n, m, vehicle_length_m=5.0)
    rho, v, w = net.split_x(x)
    i0 = (0 * n + 3) * m  # model direction 0 = SUMO ccw, link 3, segment 0
    f = 0.5 / m
    assert rho[i0] == pytest.approx(((1 - f) * 30.0 + f * 10.0) * 10.0 / 5.0)
    others = np.delete(np.arange(net.n_seg), np.arange(i0, i0 + m))
    assert np.allclose(rho[others], 20.0)  # 10 % x 10 / 5 m
    assert np.allclose(v, 72.0)  # 20 m/s
    assert w[2 * 3 + 1] == 7.0 and w.sum() == 7.0  # origin 2k+1 = model dir 1 = SUMO cw


def test_missing_speed_takes_the_equilibrium_speed() -> None:
    n = 6
    net = beltway(BeltwayLayout(n_interchanges=n, spacing_km=2.5, seg_target_km=2.5, lanes=1),
                  params=MetanetParams(step_h=15.0 / 3600.0))
    x = estimate_state(net, _ramps(n, occ=0.0, speed_mps=math.nan), n, 1, 5.0)
    _, v, _ = net.split_x(x)
    assert np.allclose(v, net.v_free_kmh, rtol=1e-4)  # density floored at 0.1 veh/km/lane


def test_od_matrix_and_forecast_from_the_scenario() -> None:
    sc, _ = load(SCENARIO)
    n = road_spec(sc).network.params.interchanges
    od = od_matrix(road_spec(sc).demand.flows, n)
    assert np.all(np.diag(od) == 0) and np.all(od >= 0)
    mean_rate = {f.route: float(np.mean(np.asarray(f.profile, float)[:, 1])) for f in road_spec(sc).demand.flows.values()}
    assert od.sum() == pytest.approx(sum(mean_rate.values()))
    assert od[0, n // 2] == pytest.approx(mean_rate[f"od_0_{n // 2}_ccw"] + mean_rate[f"od_0_{n // 2}_cw"])
    fc = DemandForecast(sc, n)
    peak_t = 900.0
    expected = sum(np.interp(peak_t, *np.asarray(f.profile, float).T) for f in road_spec(sc).demand.flows.values()
                   if f.route.startswith("od_0_"))
    assert fc(np.array([peak_t]))[0, 0] == pytest.approx(expected)


def test_missing_calibration_gives_defaults(tmp_path: Path) -> None:
    fd = load_calibration(str(tmp_path / "nope.json"))
    assert fd["v_free_kmh"] == 100.0 and "source" not in fd


def test_mpc_solver_failure_falls_back_to_alinea_and_is_logged() -> None:
    """A CPU-time safety net nobody can meet: every control step is an ALINEA fallback, logged and counted,
    and each solve the safety net ended is logged as machine-dependent."""
    from corridor.run import simulate

    sc, _ = load(SCENARIO, ["controllers.ramps={type: ramp_mpc, params: {max_cpu_time_s: 0.0001}}",
                            "duration=130"])
    metrics, ctx, _ = simulate(sc, seed=0)
    steps = 3  # decisions at t = 0, 60, 120 s
    assert metrics["mpc_solves"] == steps
    assert metrics["mpc_fallbacks"] == steps
    assert metrics["events_fallback"] == steps
    assert metrics["mpc_cpu_capped"] == steps and len(ctx.events.of_kind("mpc_cpu_cap")) == steps
    assert all(e.source == "ramps" for e in ctx.events.of_kind("fallback"))


def test_calibration_is_found_from_any_working_directory(tmp_path, monkeypatch) -> None:
    from corridor.traffic.macro.loop_state import load_calibration

    monkeypatch.chdir(tmp_path)  # not the repository: the packaged scenarios folder must still be found
    fd = load_calibration("ramp_metering.calibration.json")
    assert str(fd.get("source", "")).endswith("scenarios/ramp_metering.calibration.json")
