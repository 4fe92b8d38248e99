"""``road: X`` is the loader's shorthand of the backend entry ``backends.road = {type: sumo, params: X}``:
both spellings load the same scenario, override paths reach the field whichever spelling the file
uses, and errors name the field as the file spelled it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from corridor.batch import expand
from corridor.errors import ScenarioError
from corridor.scenario import load
from corridor.traffic.sumo.road_spec import RoadSpec, road_spec
from tests.conftest import SCENARIOS

MERGING = SCENARIOS / "merging.yaml"


@pytest.fixture()
def full(tmp_path: Path) -> Path:
    """merging.yaml with the road spelled as a backend entry (and the randomize paths unchanged)."""
    data = yaml.safe_load(MERGING.read_text())
    data["backends"] = {"road": {"type": "sumo", "params": data.pop("road")}, **data.get("backends", {})}
    path = tmp_path / "full.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_both_spellings_give_the_same_scenario(full):
    short, _ = load(MERGING)
    long, _ = load(full)
    assert short == long
    assert list(short.backends)[0] == "road" and short.backends["road"].type == "sumo"
    assert isinstance(road_spec(short), RoadSpec) and not hasattr(short, "road")


@pytest.mark.parametrize("path", ["road.demand.scale", "backends.road.params.demand.scale"])
def test_an_override_reaches_the_field_in_either_spelling(full, path):
    for file in (MERGING, full):
        sc, raw = load(file, [f"{path}=1.3"])
        assert road_spec(sc).demand.scale == 1.3
        run = expand(sc, raw, str(file), runs=1, variants=["sumo_default"])[0]
        assert not any(p.endswith("demand.scale") for p in run.draws)  # the --set field is not drawn


def test_randomize_and_sweep_paths_through_the_shorthand_work_on_the_full_spelling(full):
    sc, raw = load(full, ["sweep.sumo_default.road.demand.scale=0.5"])
    run = expand(sc, raw, str(full), runs=1, variants=["sumo_default"])[0]
    assert "road.demand.scale" in run.draws  # a randomize path spelled road.*
    from corridor.scenario import apply_overrides, validate

    vsc = validate(apply_overrides(run.base, {**run.overrides, "road.demand.scale": 0.5}), "x")
    assert road_spec(vsc).demand.scale == 0.5


def test_errors_name_the_field_as_the_file_spelled_it(full):
    bad = "demand.flows.main_car.flow_vph=-1"
    with pytest.raises(ScenarioError, match=r"merging.yaml: road\.demand\.flows\.main_car\.flow_vph: must be"):
        load(MERGING, [f"road.{bad}"])
    with pytest.raises(ScenarioError, match=r"full.yaml: backends\.road\.params\.demand\.flows\.main_car\.flow_vph:"):
        load(full, [f"road.{bad}"])
    with pytest.raises(ScenarioError, match=r"road\.network\.params\.mainline_lanes: must be greater"):
        load(MERGING, ["road.network.params.mainline_lanes=0"])
    with pytest.raises(ScenarioError, match=r"road\.network\.type: unknown network kind 'nope'"):
        load(MERGING, ["road.network.type=nope"])


def test_both_spellings_at_once_is_an_error(tmp_path):
    p = tmp_path / "both.yaml"
    p.write_text(f"extends: {MERGING}\nbackends: {{road: {{type: sumo}}}}\n")
    with pytest.raises(ScenarioError, match="road: is the shorthand of backends.road, which is given too"):
        load(p)


def test_network_params_are_the_builders_typed_model_and_unknown_nested_keys_exit_2(capsys):
    from corridor.cli import main
    from corridor.traffic.networks.beltway import BeltwayParams

    sc, _ = load(SCENARIOS / "ramp_metering.yaml")
    params = road_spec(sc).network.params
    assert isinstance(params, BeltwayParams) and params.lanes == 2
    assert main([str(SCENARIOS / "ramp_metering.yaml"), "--set", "road.network.params.bogus=1"]) == 2
    err = capsys.readouterr().err
    assert "road.network.params.bogus: unknown key" in err and err.count("\n") == 1
