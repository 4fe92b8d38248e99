"""JSBSim fleet: silent loading, initial conditions in ENU, stepping, snapshot export."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.snapshot import Kind, WorldSnapshot
from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet, quiet_fds

ORIGIN = (47.3769, 8.5417, 408.0)


def test_loading_prints_nothing(capfd: pytest.CaptureFixture[str]) -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (0.0, 0.0, 20.0))
    fleet.add("c", "c172x", (0.0, -500.0, 300.0), heading_rad=0.0, speed_mps=50.0)
    fleet.step(0.5)
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_quiet_fds_hides_c_level_writes_but_restores(capfd: pytest.CaptureFixture[str]) -> None:
    import os

    with quiet_fds():
        os.write(1, b"hidden-out\n")
        os.write(2, b"hidden-err\n")
    os.write(1, b"visible\n")
    out, err = capfd.readouterr()
    assert out == "visible\n" and err == ""


def test_initial_position_and_velocity_in_enu() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (120.0, -80.0, 35.0), heading_rad=1.0)
    fleet.add("c", "c172x", (-2000.0, 300.0, 400.0), heading_rad=np.pi / 2, speed_mps=50.0)
    s = fleet.state()
    assert np.abs(s.position[0] - [120.0, -80.0, 35.0]).max() < 0.01
    assert np.abs(s.position[1] - [-2000.0, 300.0, 400.0]).max() < 0.01
    assert s.yaw[0] == pytest.approx(1.0, abs=1e-6)
    # the c172 flies north (ENU yaw pi/2) at its trimmed airspeed
    assert s.velocity[1, 1] == pytest.approx(50.0, abs=1.0)
    assert abs(s.velocity[1, 0]) < 2.0
    assert s.airspeed[1] == pytest.approx(50.0, abs=1.0)
    assert fleet.get_property("q", "position/h-agl-ft") == pytest.approx(35.0 / 0.3048, abs=0.1)


def test_step_counts_substeps_and_c172_moves_at_its_speed() -> None:
    fleet = JSBSimFleet(ORIGIN, rate_hz=120.0)
    fleet.add("c", "c172x", (0.0, 0.0, 300.0), heading_rad=0.0, speed_mps=50.0)
    fleet.step(0.1)
    assert fleet.t_s == pytest.approx(12 / 120.0)
    assert fleet.get_property("c", "simulation/sim-time-sec") == pytest.approx(0.1, abs=1e-9)
    fleet.step(1.9)
    x = fleet.state().position[0]
    # 2 s east at ~50 m/s: ~100 m (closed form d = v t, small speed variation allowed)
    assert x[0] == pytest.approx(100.0, abs=4.0)
    assert abs(x[1]) < 3.0


def test_snapshot_part_kinds_sizes_and_concatenation() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q1", "F450", (0.0, 0.0, 20.0))
    fleet.add("c1", "c172x", (0.0, 1000.0, 300.0), heading_rad=np.pi, speed_mps=45.0)
    snap = fleet.snapshot_part()
    assert list(snap.ids) == ["q1", "c1"]
    assert list(snap.kind) == [Kind.UAV, Kind.AIRCRAFT]
    assert np.allclose(snap.size, [[0.45, 0.45, 0.2], [8.3, 11.0, 2.7]])
    assert snap.heading[1] == pytest.approx(np.pi, abs=1e-3) or snap.heading[1] == pytest.approx(-np.pi, abs=1e-3)
    merged = WorldSnapshot.from_parts(1.0, [snap, WorldSnapshot()])
    assert len(merged) == 2 and merged.position.shape == (2, 3)


def test_rejects_unknown_model_and_duplicate_ids() -> None:
    fleet = JSBSimFleet(ORIGIN)
    with pytest.raises(ValueError, match="unknown model"):
        fleet.add("x", "B747", (0.0, 0.0, 100.0))
    fleet.add("q", "F450", (0.0, 0.0, 10.0))
    with pytest.raises(ValueError, match="duplicate"):
        fleet.add("q", "F450", (1.0, 0.0, 10.0))
