"""Loader hardening (issue 18): hostile or broken input gives one line ``FILE: field.path: what is
wrong`` (a ``ScenarioError``, exit 2 from the CLI), never a traceback, a hang, or file content."""

from __future__ import annotations

from pathlib import Path

from corridor.cli import main
from tests.conftest import REPO, SCENARIOS

MERGING = SCENARIOS / "merging.yaml"


def run_cli(capsys, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    return code, capsys.readouterr().err.strip()


def assert_one_line(code: int, err: str, *needles: str, max_len: int = 300) -> None:
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert len(err.replace(str(REPO), "")) < max_len, err  # where the repository is checked out does not count
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err


# ---------------------------------------------------------------- item 10: scenario by name
def test_unknown_packaged_name_lists_the_packaged_scenarios(capsys):
    code, err = run_cli(capsys, "no_such_scenario")
    assert_one_line(code, err, "'no_such_scenario'", "packaged:", "merging", "uav_encounter")


def test_long_scenario_name_is_clipped(capsys):
    code, err = run_cli(capsys, "x" * 5000)
    assert_one_line(code, err, "packaged:", max_len=400)


def test_packaged_name_still_resolves():
    from corridor.scenario import resolve_scenario

    assert resolve_scenario("merging") == MERGING


# ---------------------------------------------------------------- helpers for file cases
import os  # noqa: E402

import pytest  # noqa: E402

from corridor.errors import ScenarioError  # noqa: E402
from corridor.scenario import load  # noqa: E402
from corridor.traffic.sumo.road_spec import road_spec  # noqa: E402


def write(tmp_path: Path, text: str | bytes, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_text(text)
    return p


def child(tmp_path: Path, body: str, name: str = "s.yaml") -> Path:
    return write(tmp_path, f"extends: {MERGING}\n{body}", name)


# ---------------------------------------------------------------- item 1: not UTF-8
def test_binary_file_is_one_line(capsys, tmp_path):
    p = write(tmp_path, b"name: x\n\x80\xff\xfe\x00binary\n")
    assert_one_line(*run_cli(capsys, str(p)), "not a UTF-8 text file")


# ---------------------------------------------------------------- item 2: deep nesting
def test_deeply_nested_yaml_is_one_line(capsys, tmp_path):
    p = write(tmp_path, "name: x\nmetrics: " + "[" * 5000 + "]" * 5000 + "\n")
    assert_one_line(*run_cli(capsys, str(p)), "nested deeper than 64 levels")


def test_deeply_nested_set_value_is_not_a_traceback(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "metrics=" + "[" * 5000 + "]" * 5000)
    assert_one_line(code, err, "metrics")


def test_set_key_with_thousands_of_levels(capsys):
    assert_one_line(*run_cli(capsys, str(MERGING), "--set", "a." * 5000 + "b=1"), "levels")


# ---------------------------------------------------------------- item 3: duplicate keys
def test_duplicate_key_names_key_and_both_lines(capsys, tmp_path):
    p = child(tmp_path, "duration: 30\nwarmup: 0\nduration: 60\n")
    assert_one_line(*run_cli(capsys, str(p)), "duplicate key 'duration' (lines 2 and 4)")


def test_duplicate_key_in_nested_flow_mapping(tmp_path):
    p = child(tmp_path, "origin: {lat: 1, lat: 2}\n")
    with pytest.raises(ScenarioError, match=r"duplicate key 'lat' \(lines 2 and 2\)"):
        load(p)


def test_merge_key_override_is_not_a_duplicate(tmp_path):
    p = child(tmp_path, "name: child\norigin: {<<: {lat: 1, lon: 2}, lat: 3}\n")
    assert load(p)[0].origin.lat == 3


# ---------------------------------------------------------------- item 4: size and alias bombs
def test_extends_dev_zero_returns_at_once(capsys, tmp_path):
    p = write(tmp_path, "extends: /dev/zero\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "/dev/zero: not a regular file")


def test_file_over_the_size_limit(capsys, tmp_path):
    p = write(tmp_path, "name: x\ndescription: " + "a" * 1_100_000 + "\n")
    assert_one_line(*run_cli(capsys, str(p)), "larger than 1000 kB")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs a FIFO")
def test_extends_a_fifo_does_not_block(capsys, tmp_path):
    os.mkfifo(tmp_path / "pipe")
    p = write(tmp_path, "extends: pipe\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "not a regular file")


BOMB = "\n".join(["name: x", "randomize:", "  road.demand.scale: &a {choice: [1, 1, 1, 1, 1, 1, 1, 1, 1]}"]
                 + [f"  l{i}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 9) + "]" for i in range(9)]) + "\n"


def test_billion_laughs_alias_bomb_is_refused(capsys, tmp_path):
    p = write(tmp_path, BOMB)
    assert_one_line(*run_cli(capsys, str(p)), "more than 200000 values once aliases are expanded")


def test_recursive_alias_is_refused(tmp_path):
    p = child(tmp_path, "metrics: &m [a, *m]\n")
    with pytest.raises(ScenarioError, match="alias inside its own anchor"):
        load(p)


def test_a_few_aliases_still_work(tmp_path):
    p = child(tmp_path, "name: child\norigin: &o {lat: 1, lon: 2}\ndescription: &d text\nmetrics: [*d, *d]\n")
    assert load(p)[0].metrics == ["text", "text"]


# ---------------------------------------------------------------- item 5: what extends may name
def test_extends_a_directory(capsys, tmp_path):
    p = write(tmp_path, f"extends: {tmp_path}\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "is a directory")


def test_extends_a_path_with_nul(capsys, tmp_path):
    p = write(tmp_path, 'extends: "a\\0b.yaml"\nname: x\n')
    assert_one_line(*run_cli(capsys, str(p)), "NUL byte")


def test_extends_a_symlink_loop(capsys, tmp_path):
    (tmp_path / "l1").symlink_to(tmp_path / "l2")
    (tmp_path / "l2").symlink_to(tmp_path / "l1")
    p = write(tmp_path, "extends: l1\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "l1", "cannot read")


def test_extends_not_a_path(capsys, tmp_path):
    p = write(tmp_path, "extends: [a, b]\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "extends: must be a file path")


SECRET = "hunter2-secret"


@pytest.mark.parametrize("content", [
    f"root:{SECRET}:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n",  # /etc/shadow: a mapping of odd keys
    f"{SECRET}: 'unclosed\n",  # a YAML error whose problem PyYAML quotes
    f"key: \"{SECRET}\\q\"\n",  # unknown escape: PyYAML quotes the character, str(exc) the whole line
    f"a: *{SECRET}\n",  # undefined alias: PyYAML quotes its name
    f"a: !!{SECRET} x\n",  # unknown tag
    f"a: 2024-13-45\nb: {SECRET}\n",  # a date that is not one (ValueError inside PyYAML)
    f"[{SECRET}]\n",
    f"\t{SECRET}\n",
])
def test_extends_of_a_non_scenario_file_never_echoes_its_content(capsys, tmp_path, content):
    write(tmp_path, content, "secret.txt")
    p = write(tmp_path, "extends: secret.txt\nname: x\n")
    code, err = run_cli(capsys, str(p))
    assert_one_line(code, err, "secret.txt")
    assert SECRET not in err and "daemon" not in err


def test_extends_etc_shadow_like_file_says_not_a_scenario(capsys, tmp_path):
    write(tmp_path, "root:*:19000:0:99999:7:::\n", "shadow")
    p = write(tmp_path, "extends: shadow\nname: x\n")
    assert_one_line(*run_cli(capsys, str(p)), "not a scenario file", "line 1")


# ---------------------------------------------------------------- item 6: names become file names
@pytest.mark.parametrize("name", ["a" * 300, "a/b", "..", "x..y", "a\\0b", "-x", ".hidden", "a b"])
def test_hostile_scenario_name(capsys, name):
    code, err = run_cli(capsys, str(MERGING), "--set", f'name="{name}"')
    assert_one_line(code, err, "name:", "names files")


@pytest.mark.parametrize("name", ["../../etc", "a/b", "x" * 100])
def test_hostile_variant_name(capsys, name):
    code, err = run_cli(capsys, str(MERGING), "--set", f'sweep={{"{name}": {{}}}}')
    assert_one_line(code, err, "sweep: variant name", "names files")


def test_packaged_scenarios_still_load():
    for path in sorted((REPO / "scenarios").glob("*.yaml")):
        sc, _ = load(path)
        assert sc.name == path.stem


# ---------------------------------------------------------------- item 7: randomize distributions
@pytest.mark.parametrize(("dist", "needle"), [
    ("{uniform: [300, 200]}", "low <= high"),
    ("{uniform: [0, .inf]}", "finite"),
    ("{uniform: [.nan, 1]}", "finite"),
    ("{uniform: [-1e308, 1e308]}", "finite low <= high"),
    ("{normal: [1, -1]}", "std >= 0"),
    ("{integers: [5, 1]}", "low <= high"),
    ("{integers: [0, 100000000000000000000000]}", "2**62"),
    ("{choice: []}", "1 to 10000 options"),
])
def test_invalid_distribution_rejected_at_load(capsys, dist, needle):
    code, err = run_cli(capsys, str(MERGING), "--set", f"randomize.road.demand.scale={dist}")
    assert_one_line(code, err, "randomize.road.demand.scale", needle)


def test_randomize_path_not_in_the_schema(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "randomize.road.demand.scael={uniform: [0.9, 1.1]}")
    assert_one_line(code, err, "randomize.road.demand.scael", "unknown key")


def test_randomize_draw_outside_the_field_bounds(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "randomize.channels.v2x.loss.p={uniform: [0.5, 2]}")
    assert_one_line(code, err, "randomize.channels.v2x.loss.p", "the draw '2.0' is invalid")


def test_randomize_path_valid_in_a_variant_only_is_accepted():
    sc, _ = load(MERGING, ["randomize.controllers.merge.params.stale_after_s={uniform: [0.5, 1.0]}"])
    assert "controllers.merge.params.stale_after_s" in sc.randomize


# ---------------------------------------------------------------- item 8: plausible bounds
@pytest.mark.parametrize(("setting", "needle"), [
    ("dt=1e-9", "dt: must be greater than or equal to 0.001 s"),
    ("dt=100", "dt: must be less than or equal to 10 s"),
    ("duration=1e308", "duration: must be less than or equal to 2592000 s"),
    ("duration=.inf", "duration: must be a finite number"),
    ("duration=2592000", "duration / dt = 2.59e+07"),  # fine in steps at dt 0.1 ...
    ("road.demand.flows.main_truck.flow_vph=1e12", "flow_vph: must be less than or equal to 20000 veh/h"),
    ("road.demand.flows.ramp_car.profile=[[0, 1e9]]", "profile rates must be <= 20000 veh/h"),
    ("road.demand.scale=100", "rate x scale"),
    ("seed=4294967296", "seed: must be less than or equal to 4294967295"),
    ("origin.alt=.nan", "origin.alt: must be a finite number"),
    ("monitors.ssm.params.ttc_threshold_s=.inf", "monitors.ssm.params.ttc_threshold_s: must be a finite number"),
    ("road.sumo.step_length=1e-9", "step_length: must be greater than or equal to 0.001 s"),
])
def test_plausible_bounds(capsys, setting, needle):
    if needle.startswith("duration / dt"):  # at dt 0.1 30 days are 2.6e7 steps: allowed (loaded, not run)
        sc, _ = load(MERGING, [setting, "warmup=0"])
        assert sc.duration == 2592000
        return
    code, err = run_cli(capsys, str(MERGING), "--set", setting, "--set", "warmup=0")
    assert_one_line(code, err, needle)


def test_step_count_bounded(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "duration=2592000", "--set", "dt=0.001")
    assert_one_line(code, err, "duration / dt = 2.59e+09 steps, must be <= 1e+08")


@pytest.mark.parametrize("args", [
    "[--fcd-output, /tmp/x]", "[--output-prefix, x]", "[--log, x]", "[--error-log, x]",
    "[--configuration-file, x]", "[-c, x]", "['--tripinfo-output=x']", "[--collision-output, x]",
    "[--device.fcd.probability, '1']", "[--lateral-resolution, '0.8', --summary-output, x]",
])
def test_sumo_extra_args_that_write_files_are_refused(capsys, args):
    code, err = run_cli(capsys, str(MERGING), "--set", f"road.sumo.extra_args={args}")
    assert_one_line(code, err, "road.sumo.extra_args", "writes files", "allowed (after --): lateral-resolution")


def test_sumo_extra_args_allow_list_accepted():
    sc, _ = load(MERGING, ["road.sumo.extra_args=[--lateral-resolution, 0.8, --time-to-teleport.highways, 10, "
                           "--collision.stoptime, 1, --step-method.ballistic, 'true']"])
    assert road_spec(sc).sumo.extra_args[:2] == ["--lateral-resolution", "0.8"]


# ---------------------------------------------------------------- item 9: echoed values are clipped
def test_megabyte_component_type_is_clipped(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "monitors.ssm.type=" + "x" * 1_000_000)
    assert_one_line(code, err, "monitors.ssm.type: unknown monitor 'xxx", "…")


def test_megabyte_unknown_key_is_clipped(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "origin." + "k" * 1_000_000 + "=1")
    assert_one_line(code, err, "origin.'kkk", "unknown key")


def test_long_plain_key_is_a_yaml_error_without_the_key(capsys, tmp_path):
    p = child(tmp_path, "origin: {" + "k" * 100_000 + ": 1}\n")
    code, err = run_cli(capsys, str(p))
    assert_one_line(code, err, "invalid YAML: line 2")
    assert "kkkk" not in err


def test_megabyte_set_item_is_clipped(capsys):
    assert_one_line(*run_cli(capsys, str(MERGING), "--set", "x" * 1_000_000), "expected FIELD.PATH=VALUE")


def test_megabyte_vtype_is_clipped(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "road.demand.flows.main_truck.vtype=" + "v" * 100_000)
    assert_one_line(code, err, "unknown vehicle type 'vvv")


# ---------------------------------------------------------------- item 11: a variant's own parameters
def test_param_of_a_variant_only_controller_says_how_to_set_it(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "controllers.merge.params.policy=fifo")
    assert_one_line(code, err, "controllers.merge is set per variant",
                    "--set sweep.VARIANT.controllers.merge.params.policy=VALUE (works for v2x_fifo, v2x_cps)")


def test_param_of_one_variant_type_names_that_variant(capsys):
    code, err = run_cli(capsys, str(SCENARIOS / "ramp_metering.yaml"), "--set",
                        "controllers.ramps.params.weight_rate_change=1")
    assert_one_line(code, err, "--set sweep.VARIANT.controllers.ramps.params.weight_rate_change=VALUE (works for mpc)")


def test_a_real_typo_gets_no_variant_hint(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "monitors.ssm.params.ttc_treshold_s=2")
    assert_one_line(code, err, "did you mean 'ttc_threshold_s'")
    assert "per variant" not in err


def test_set_a_parameter_of_one_variant():
    _, raw = load(MERGING, ["sweep.v2x_cps.controllers.merge.params.coordinator.control_zone_m=300",
                            "sweep.v2x_fifo.road.demand.scale=1.2"])
    assert raw["sweep"]["v2x_cps"]["controllers.merge"]["params"]["coordinator"]["control_zone_m"] == 300
    assert raw["sweep"]["v2x_fifo"]["road.demand.scale"] == 1.2  # a new dotted key, not a nested 'road' dict
    assert raw["sweep"]["v2x_fifo"]["controllers.merge"]["params"]["policy"] == "fifo"  # untouched


def test_a_variant_set_from_the_command_line_is_validated_at_load(capsys):
    code, err = run_cli(capsys, str(MERGING), "--set", "sweep.v2x_cps.controllers.merge.params.polcy=fifo")
    assert_one_line(code, err, "[sweep.v2x_cps]", "controllers.merge.params.polcy: unknown key (did you mean 'policy'?)")


def test_set_a_randomize_path():
    sc, _ = load(MERGING, ["randomize.road.demand.scale.uniform=[0.8, 1.2]"])
    assert sc.randomize["road.demand.scale"].uniform == (0.8, 1.2)


# ---------------------------------------------------------------- item 12: typed nested method params
UAV = SCENARIOS / "uav_encounter.yaml"


@pytest.mark.parametrize("setting", [
    "controllers.avoid.params.potential_field={bogus_gain: 3}",
    "controllers.avoid.params.control_tube={bogus_gain: 3}",
    "sweep.potential_field.controllers.avoid.params.potential_field.bogus_gain=3",
])
def test_unknown_nested_avoidance_param_fails_at_load(capsys, setting):
    code, err = run_cli(capsys, str(UAV), "--set", setting)
    assert_one_line(code, err, "controllers.avoid.params.", ".bogus_gain: unknown key")


def test_nested_avoidance_param_bounds_checked_at_load(capsys):
    code, err = run_cli(capsys, str(UAV), "--set", "controllers.avoid.params.potential_field.uav_weight=-1")
    assert_one_line(code, err, "potential_field.uav_weight: must be greater than or equal to 0")


def test_avoidance_methods_get_the_same_params_as_before():
    from corridor.controllers.uav.components import UavAvoidanceParams
    from corridor.controllers.uav.control_tube import ControlTubeParams
    from corridor.controllers.uav.potential_field import PotentialFieldParams

    p = UavAvoidanceParams.model_validate({"potential_field": {"vortex_gain": 2}, "control_tube": {"step_s": 0.4}})
    assert p.potential_field == PotentialFieldParams(vortex_gain=2)
    # the tube's period_s still defaults to the controller's period: only the fields given are passed on
    assert p.control_tube.model_dump(exclude_unset=True) == {"step_s": 0.4}
    assert UavAvoidanceParams().control_tube.model_dump(exclude_unset=True) == {}
    assert UavAvoidanceParams().potential_field == PotentialFieldParams()
    assert ControlTubeParams(**{"period_s": 0.2, **p.control_tube.model_dump(exclude_unset=True)}).period_s == 0.2
