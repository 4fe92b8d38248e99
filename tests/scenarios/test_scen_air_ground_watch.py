"""air_ground_watch: road and air in one run (briefly), determinism, and the MAVLink bytes a run writes
decode with pymavlink's parser, traffic estimates included."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.run import simulate
from corridor.scenario import apply_overrides, load, validate
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "air_ground_watch.yaml"
MACHINE = {"wall_s", "rtf", "wall_per_sim_s", "cpu_per_sim_s", "mpc_solve_p50_s", "mpc_solve_p95_s", "tube_solve_ms_mean"}


def variant(name: str, duration_s: float, *sets: str):
    _, raw = load(SCENARIO, [f"duration={duration_s}", *sets])
    return validate(apply_overrides(raw, raw["sweep"][name]), str(SCENARIO))


def test_road_and_air_share_one_run(tmp_path):
    sc = variant("loops_failed_uav_ct", 12.0, "backends.link.params.log_path=mavlink/link.tlog")
    metrics, ctx, _ = simulate(sc, 0, str(tmp_path), run_id="ct-s0")
    assert metrics["aircraft"] == 8  # six patrol quads, the c172x, the medical drone
    assert metrics["vehicles_departed"] > 0 and metrics["loops_failed"] == 10  # 30 % of 32 stations
    assert metrics["camera_estimates_sent"] > 0
    assert metrics["fusion_uav_estimates"] > 0  # arrived over the channel
    assert 0.0 < metrics["coverage"] <= 1.0
    assert metrics["nmac_uav_uav"] == 0 and metrics["collisions"] == 0
    assert metrics["link_sent"] > 0 and metrics["mavlink_bad_data"] == 0
    # the raw MAVLink log decodes with pymavlink's own parser (the generated dialect)
    from corridor.vehicles.mavlink.dialect import dialect

    data = (tmp_path / "mavlink" / "link-ct-s0.tlog").read_bytes()
    parser = dialect().MAVLink(None)
    msgs = parser.parse_buffer(data) or []
    types = {m.get_type() for m in msgs}
    assert {"HEARTBEAT", "GLOBAL_POSITION_INT", "ADSB_VEHICLE", "TRAFFIC_SEGMENT_ESTIMATE"} <= types
    est = [m for m in msgs if m.get_type() == "TRAFFIC_SEGMENT_ESTIMATE"]
    assert len(est) == metrics["camera_estimates_sent"]
    assert all(0 <= m.segment < 16 and m.direction == m.segment // 8 and m.density >= 0 for m in est)
    assert parser.total_receive_errors == 0


def test_same_seed_same_run(tmp_path):
    """Two runs of one seed give the same row (machine measurements aside) with the scenario as it is:
    the MPC's budget is IPOPT's iteration count, not CPU time, so load does not enter; 61 s covers two
    MPC decisions (a cold and a warm-started solve) and the camera/fusion chain."""
    sc = variant("loops_failed_uav_pf", 61.0)
    a, _, _ = simulate(sc, 3, None)
    b, _, _ = simulate(sc, 3, None)
    assert a["mpc_solves"] == 2 and a["mpc_cpu_capped"] == 0 and a["fusion_uav_estimates"] > 0
    assert a.keys() == b.keys()
    for k in a:
        if k in MACHINE:
            continue
        va, vb = a[k], b[k]
        if isinstance(va, float) and math.isnan(va):
            assert isinstance(vb, float) and math.isnan(vb), k
        else:
            assert va == vb, k


def test_loops_variant_has_no_aircraft():
    metrics, _, _ = simulate(variant("loops", 6.0), 0, None)
    assert metrics["aircraft"] == 0
    assert "loops_failed" not in metrics
    assert np.isfinite(metrics["tts_vh"])


def test_camera_needs_the_traffic_dialect(tmp_path):
    sc = variant("loops_failed_uav_pf", 2.0, "backends.link.params.dialect=common")
    with pytest.raises(ValueError, match="dialect: corridor_traffic"):
        simulate(sc, 0, None)


def test_perfect_information_baseline_feeds_the_mpc_the_ground_truth():
    """``segment_truth`` (the diagnostic baseline: the MPC on SUMO's segment truth) hands the MPC what
    ``segment_watch`` measures as truth (one SUMO step earlier: DECIDE reads the last integrated state),
    taken to the station scale by the scenario's station map."""
    from corridor.traffic.macro.loop_state import load_station_map

    sc = variant("loops_failed", 121.0, "controllers.truth.type=segment_truth",
                 "controllers.ramps.params.estimator=truth", "monitors.watch.params.start_s=120")
    _, ctx, _ = simulate(sc, 0, None)
    g = load_station_map(sc.controllers["ramps"].params["station_map"])
    mpc = np.array([ctx.signals.get(f"mpc_rho_{i}")[1] for i in range(16)])  # [segment, decision]
    true = np.array([ctx.signals.get(f"rho_true_{i}")[1][0] for i in range(16)])  # t = 120 s: the first
    assert list(ctx.signals.get("mpc_rho_0")[0]) == [0.0, 60.0, 120.0]  # vehicles reach the ring at ~90 s
    assert np.all(mpc[:, 0] == 0.1)  # empty ring at t = 0 (floored)
    expected = np.maximum(g.to_station(true), 0.1)
    assert true.max() > 1.0 and np.max(np.abs(mpc[:, 2] - expected)) <= 1.0  # [veh/km/lane]: ~2 vehicles
