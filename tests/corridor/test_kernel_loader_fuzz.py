"""Property-based fuzz of the scenario loader (issue 18): any mutation of a packaged scenario file is
either a valid scenario or a ``ScenarioError`` of one line (< 300 characters); never another
exception, never a hang."""

from __future__ import annotations

import copy
import math
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from corridor.cli import main
from corridor.errors import ScenarioError
from corridor.scenario import Scenario, load, validate
from tests.conftest import REPO, SCENARIOS

PACKAGED = sorted((REPO / "scenarios").glob("*.yaml"))
RAW = {p.name: yaml.safe_load(p.read_text()) for p in PACKAGED}
FUZZ = settings(max_examples=60, deadline=2000, suppress_health_check=[HealthCheck.too_slow],
                derandomize=True, database=None)


def _paths(data: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(data, dict):
        for k, v in data.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += _paths(v, (*prefix, i))
    return out


NASTY = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e308, -1e308, 1e-308, 2**64, -1]),
    st.text(max_size=30), st.text(alphabet="/.\\\x00é日\u202e", min_size=1, max_size=10),
    st.just("x" * 5000), st.lists(st.integers(), max_size=3), st.dictionaries(st.text(max_size=5), st.integers(),
                                                                             max_size=2),
)


@st.composite
def mutated(draw: st.DrawFn) -> tuple[str, dict[str, Any]]:
    name = draw(st.sampled_from(sorted(RAW)))
    data = copy.deepcopy(RAW[name])
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(data)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = data
        for k in path[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(["delete", "replace", "replace", "wrap"]))
        if op == "delete" and isinstance(parent, dict):
            del parent[path[-1]]
        elif op == "wrap":
            parent[path[-1]] = [parent[path[-1]]]  # a list where a map or a value was
        else:
            parent[path[-1]] = draw(NASTY)
    return name, data


def _check_outcome(fn, *args) -> None:
    try:
        result = fn(*args)
    except ScenarioError as exc:
        msg = str(exc)
        assert "\n" not in msg and len(msg) < 300, msg
        return
    sc = result[0] if isinstance(result, tuple) else result
    assert isinstance(sc, Scenario)


@FUZZ
@given(mutated())
def test_validate_of_mutated_data_is_a_scenario_or_one_line(case):
    name, data = case
    _check_outcome(validate, data, name)


@FUZZ
@given(case=mutated())
def test_load_of_mutated_file_is_a_scenario_or_one_line(tmp_path_factory, case):
    name, data = case
    try:
        text = yaml.safe_dump(data, allow_unicode=True)
    except (yaml.YAMLError, ValueError):
        return
    p = tmp_path_factory.mktemp("fuzz") / name
    p.write_text(text, encoding="utf-8")
    _check_outcome(load, p)


@FUZZ
@given(name=st.sampled_from([p.name for p in PACKAGED]), data=st.data())
def test_load_of_byte_damaged_file_is_a_scenario_or_one_line(tmp_path_factory, name, data):
    raw = bytearray((SCENARIOS / name).read_bytes())
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(raw) - 1))
        op = data.draw(st.sampled_from(["flip", "insert", "cut"]))
        if op == "flip":
            raw[i] = data.draw(st.integers(0, 255))
        elif op == "insert":
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=8))
        else:
            del raw[i:i + data.draw(st.integers(1, 40))]
    p = tmp_path_factory.mktemp("bytes") / name
    p.write_bytes(bytes(raw))
    _check_outcome(load, p)


@FUZZ
@given(name=st.sampled_from([p.name for p in PACKAGED]),
       key=st.sampled_from(["dt", "duration", "seed", "name", "warmup", "origin.lat", "sweep", "randomize",
                            "outputs.rerun_period", "metrics", "description", "road.demand.scale"]),
       value=st.one_of(st.text(max_size=40), st.floats().map(repr), st.integers().map(str),
                       st.sampled_from([".nan", ".inf", "-.inf", "1e308", "[", "{a: [", "*x", "!!python/object x"])))
def test_set_options_are_a_scenario_or_one_line(name, key, value):
    _check_outcome(load, SCENARIOS / name, [f"{key}={value}"])


@pytest.mark.parametrize("argv", [
    ["--set", "dt=.nan"], ["--set", "name=../x"], ["--set", "sweep={}"], ["--set", "randomize.x={normal: [0, -1]}"],
    ["--set", "road.sumo.extra_args=[--fcd-output, x]"], ["--set", "seed=-1"], ["--set", "=1"],
])
def test_cli_cases_exit_2_with_one_line(capsys, argv):
    code = main([str(SCENARIOS / "merging.yaml"), *argv])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and len(err) < 320, err


def test_finite_check_also_covers_yaml_nan_spelled_in_params():
    data = copy.deepcopy(RAW["merging.yaml"])
    data["monitors"]["ssm"]["params"]["ttc_threshold_s"] = math.nan
    with pytest.raises(ScenarioError, match="monitors.ssm.params.ttc_threshold_s: must be a finite number"):
        validate(data, "m.yaml")
