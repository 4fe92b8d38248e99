"""Component parameters are bounded at scenario load: a bad value is one line and exit code 2, never a
run that fails (or runs for minutes) later."""

from __future__ import annotations

import pytest

from corridor.cli import main
from corridor.errors import ScenarioError
from corridor.scenario import load
from tests.conftest import REPO

SC = REPO / "scenarios"


def one_line_exit_2(capsys, *argv: str) -> str:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    return err


def test_rate_min_above_open_rate_rejected(capsys):
    err = one_line_exit_2(capsys, str(SC / "ramp_metering.yaml"), "--set", "controllers.ramps.type=ramp_alinea",
                          "--set", "controllers.ramps.params={rate_min_vph: 2000, open_rate_vph: 1800}")
    assert "controllers.ramps.params" in err and "rate_min_vph" in err and "open_rate_vph" in err


def test_rate_min_equal_or_below_open_rate_accepted():
    load(SC / "ramp_metering.yaml", ["controllers.ramps.type=ramp_alinea",
                                     "controllers.ramps.params={rate_min_vph: 1800, open_rate_vph: 1800}"])


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_nan_or_inf_mpc_weight_rejected(capsys, value):
    err = one_line_exit_2(capsys, str(SC / "ramp_metering.yaml"), "--set", "controllers.ramps.type=ramp_mpc",
                          "--set", f"controllers.ramps.params.weight_rate_change={value}")
    assert "controllers.ramps.params.weight_rate_change" in err and "finite" in err


@pytest.mark.parametrize(("scenario", "field"), [
    ("hegyi_benchmark.yaml", "controllers.ramp.params.weight_rate_change"),
    ("uav_encounter.yaml", "backends.link.params.process_noise"),
    ("uav_encounter.yaml", "monitors.separation.params.nmac_h_m"),
    ("merging.yaml", "monitors.ssm.params.ttc_threshold_s"),
])
def test_nan_rejected_in_backend_controller_monitor_params(capsys, scenario, field):
    err = one_line_exit_2(capsys, str(SC / scenario), "--set", f"{field}=.nan")
    assert field in err and "finite" in err


@pytest.mark.parametrize(("scenario", "sets", "field"), [
    ("ramp_metering.yaml", ["controllers.ramps.type=ramp_mpc", "controllers.ramps.params.horizon_ctrl_steps=100000"],
     "controllers.ramps.params.horizon_ctrl_steps"),
    ("hegyi_benchmark.yaml", ["controllers.ramp.type=metanet_mpc", "controllers.ramp.params.horizon_ctrl_steps=100000"],
     "controllers.ramp.params.horizon_ctrl_steps"),
    ("uav_encounter.yaml", ["backends.link.params.max_tracks=100000"], "backends.link.params.max_tracks"),
    ("merging.yaml", ["controllers.merge.type=v2x_merging", "controllers.merge.params.coordinator.horizon=100000"],
     "controllers.merge.params.coordinator.horizon"),
    ("merging.yaml", ["controllers.merge.type=v2x_merging", "controllers.merge.params.coordinator.max_shift=100"],
     "controllers.merge.params.coordinator.max_shift"),
])
def test_unbounded_sizes_rejected(capsys, scenario, sets, field):
    argv = [str(SC / scenario)]
    for s in sets:
        argv += ["--set", s]
    err = one_line_exit_2(capsys, *argv)
    assert field in err and "less than or equal" in err


def test_load_raises_scenario_error():
    with pytest.raises(ScenarioError, match="weight_rate_change"):
        load(SC / "ramp_metering.yaml", ["controllers.ramps.type=ramp_mpc",
                                         "controllers.ramps.params.weight_rate_change=.nan"])


def test_control_tube_bounds():
    from pydantic import ValidationError

    from corridor.controllers.uav.control_tube import ControlTubeParams

    with pytest.raises(ValidationError):
        ControlTubeParams(n_steps=100000)
    with pytest.raises(ValidationError):
        ControlTubeParams(w_track=float("nan"))
    ControlTubeParams(n_steps=100)


@pytest.mark.parametrize("field,value", [("controller.mpc.horizon_steps", "100000"),
                                         ("controller.mpc.max_iter", "10000000"),
                                         ("controller.mpc.w_speed", ".nan")])
def test_overtaking_mpc_size_and_weights_bounded(capsys, field, value):
    err = one_line_exit_2(capsys, str(SC / "overtaking.yaml"), "--set",
                          f"controllers.overtaking.params.{field}={value}")
    assert f"controllers.overtaking.params.{field}" in err
