"""Bad input gives one line `FILE: field.path: what is wrong` and exit code 2, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from corridor.cli import main
from corridor.scenario import load
from corridor.traffic.sumo.road_spec import road_spec
from tests.conftest import SCENARIOS

MERGING = SCENARIOS / "merging.yaml"


def run_cli(capsys, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    return code, err


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def assert_one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err


def test_missing_file(capsys, tmp_path):
    assert_one_line(*run_cli(capsys, str(tmp_path / "nope.yaml")), "nope.yaml: no such file")


def test_invalid_yaml(capsys, tmp_path):
    p = write(tmp_path, "name: x\nroad: [unclosed\n")
    assert_one_line(*run_cli(capsys, str(p)), "invalid YAML", "line")


def test_wrong_type(capsys, tmp_path):
    p = write(tmp_path, f"extends: {MERGING}\nduration: soon\n")
    assert_one_line(*run_cli(capsys, str(p)), "duration:", "number")


def test_unknown_key_with_hint(capsys, tmp_path):
    p = write(tmp_path, f"extends: {MERGING}\ndurration: 10\n")
    assert_one_line(*run_cli(capsys, str(p)), "durration: unknown key (did you mean 'duration'?)")


def test_negative_flow(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "road.demand.flows.main_truck.flow_vph=-5")
    assert_one_line(code, err, "road.demand.flows.main_truck.flow_vph: must be greater than or equal to 0")


def test_set_on_missing_field(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "road.sumo.step_lenght=0.2")
    assert_one_line(code, err, "road.sumo.step_lenght: unknown key (did you mean 'step_length'?)")


def test_bad_network_param_names_its_path(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "road.network.params.accel_lane_length_m=5000")
    assert_one_line(code, err, "road.network.params", "accel_lane_length_m")


def test_unknown_component_type(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "monitors.ssm.type=surogate_safety")
    assert_one_line(code, err, "monitors.ssm.type: unknown monitor 'surogate_safety' (did you mean 'surrogate_safety'?)")


def test_set_syntax(capsys):
    assert_one_line(*run_cli(capsys, str(MERGING), "--set", "duration"), "expected FIELD.PATH=VALUE")


def test_extends_and_set_merge(tmp_path):
    p = write(tmp_path, f"extends: {MERGING}\nname: child\nduration: 30\nwarmup: 0\n")
    sc, _ = load(p, ["road.demand.scale=1.5", "metrics=[a, b]"])
    assert (sc.name, sc.duration, road_spec(sc).demand.scale, sc.metrics) == ("child", 30, 1.5, ["a", "b"])
    assert road_spec(sc).network.params.mainline_lanes == 2  # inherited


def test_extends_cycle(capsys, tmp_path):
    write(tmp_path, "extends: b.yaml\nname: a\n", "a.yaml")
    write(tmp_path, "extends: a.yaml\nname: b\n", "b.yaml")
    assert_one_line(*run_cli(capsys, str(tmp_path / "a.yaml")), "extends: cycle")


def test_scenario_is_frozen():
    sc, _ = load(MERGING)
    with pytest.raises(ValidationError):
        sc.duration = 5  # type: ignore[misc]


def test_set_value_wins_over_the_randomized_draw_of_that_field():
    from corridor.batch import expand

    sc, raw = load(MERGING, ["road.demand.scale=1.2", "channels.v2x.loss={model: bernoulli, p: 0.3}"])
    specs = expand(sc, raw, "merging.yaml", runs=3, variants=["sumo_default"])
    for s in specs:  # neither the scale nor anything beneath the loss is drawn any more
        assert "road.demand.scale" not in s.overrides and "channels.v2x.loss.p" not in s.overrides
        assert "road.demand.flows.main_car.connected_share" in s.draws  # the fields not set still are
    assert road_spec(sc).demand.scale == 1.2 and sc.channels["v2x"].loss.p == 0.3
    full, _ = load(MERGING)
    assert "road.demand.scale" in expand(full, _, "merging.yaml", runs=1)[0].draws
