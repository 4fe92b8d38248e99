"""Malformed input for the rare-event options and the Python API (issue 30): one line and exit 2, no
folder left behind, never a silently wrong number."""

from __future__ import annotations

from pathlib import Path

import pytest

from corridor.api import run
from corridor.cli import main, parse_args
from corridor.errors import CorridorError
from corridor.rare_api import estimate, falsify
from corridor.rare_event import parse_event
from tests.corridor.rare_data import GAUSS


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("args,needle", [
    (["--estimate", "nmac > 1" + "0" * 400, "--method", "naive", "--budget", "2"], "float range"),
    (["--estimate", "nmac > 1e400", "--method", "naive", "--budget", "2"], "float range"),
    (["--estimate", "nmac > 0", "--method", "falsify", "--budget", "200"], "--falsify SPEC"),
    (["--estimate", "nmac > 0", "--method", "ce", "--budget", "20"], "at least 100"),
    (["--estimate", "nmac > 0", "--method", "ce", "--budget", "60"], "at least 100"),
    (["--estimate", "nmac > 0", "--method", "splitting", "--budget", "99"], "at least 100"),
    (["--estimate", "nmac > 0", "--method", "splitting_is", "--budget", "20"], "at least 200"),
    (["--estimate", "draw.nosuch > 0", "--method", "naive", "--budget", "2"], "no column 'draw.nosuch'"),
    (["--estimate", "spec.nosuch.space < 0", "--method", "naive", "--budget", "2"], "no column 'spec.nosuch.space'"),
    (["--estimate", "nmac > 0", "--level", "spec.nope.space", "--budget", "100"], "--level"),
    (["--falsify", "nosuch", "--budget", "10"], "--falsify 'nosuch': no spec"),
    (["--estimate", "nmac > 0", "--method", "naive", "--budget", "2", "--variant", "sumo_defualt"], "sumo_defualt"),
])
def test_bad_rare_options_one_line_no_folder(args: list[str], needle: str, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "o"
    assert main([str(GAUSS), "--out", str(out), "--quiet", *args]) == 2
    assert needle in _one_line(capsys)
    assert not out.exists()  # validated before the folder is touched


def test_unknown_column_from_the_rows_is_exit_2_and_leaves_no_folder(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """The spelling --help used (min_sep_h_m) is no column: known only once a row exists, refused
    then with the real one suggested, and the folder left as if never touched."""
    out = tmp_path / "o"
    assert main([str(GAUSS), "--out", str(out), "--quiet", "--estimate", "min_sep_h_m < 1000",
                 "--method", "naive", "--budget", "2"]) == 2
    err = _one_line(capsys)
    assert "no column 'min_sep_h_m'" in err and "did you mean sep_min_h_m" in err, err
    assert not out.exists()
    # the corrected command then runs in that folder
    assert main([str(GAUSS), "--out", str(out), "--quiet", "--estimate", "sep_min_h_m < 1000",
                 "--method", "naive", "--budget", "2"]) == 0


def test_unknown_level_column_in_an_adaptive_stage(tmp_path: Path) -> None:
    out = tmp_path / "ce"
    with pytest.raises(CorridorError, match=r"--level 'sep_min_m': no column 'sep_min_m' .*did you mean sep_min_"):
        estimate(GAUSS, "nmac > 0", method="ce", budget=100, level="sep_min_m", out=out, executor="inline",
                 report=False)
    assert not out.exists()


def test_help_examples_name_real_columns() -> None:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), pytest.raises(SystemExit):
        parse_args(["--help"])
    assert "min_sep_h_m" not in buf.getvalue() and "sep_min_h_m" in buf.getvalue()


def test_method_or_level_without_estimate_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    for extra in (["--method", "ce"], ["--level", "nmac"]):
        with pytest.raises(SystemExit) as exc:
            parse_args([str(GAUSS), *extra])
        assert exc.value.code == 2
        assert "goes with --estimate" in capsys.readouterr().err


def test_event_text_is_canonical_so_resume_accepts_other_spacing(tmp_path: Path) -> None:
    assert parse_event("nmac>0").text == parse_event("nmac  >  0").text == "nmac > 0"
    out = tmp_path / "n"
    base = [str(GAUSS), "--out", str(out), "--quiet", "--no-report", "--method", "naive"]
    assert main([*base, "--estimate", "nmac > 0", "--budget", "2"]) == 0
    assert main([*base, "--estimate", "nmac>0", "--budget", "3", "--resume"]) == 0


def test_naive_estimate_with_an_error_row_exits_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two separation monitors write the same columns: every run dies at its end (an error row)."""
    sc = tmp_path / "broken.yaml"
    sc.write_text(f"extends: {GAUSS}\nmonitors:\n  sep: {{type: uav_separation, params: {{backend: null, "
                  "track_period_s: null}}\n  sep2: {type: uav_separation, params: {backend: null, "
                  "track_period_s: null}}\n")
    assert main([str(sc), "--out", str(tmp_path / "o"), "--quiet", "--no-report", "--estimate", "nmac > 0",
                 "--method", "naive", "--budget", "2"]) == 1
    err = capsys.readouterr().err
    assert "2 of 2 runs failed" in err and "written by both" in err, err


def test_zero_failures_print_no_nan() -> None:
    from corridor.estimate import estimate_lines

    data = {"event": "nmac > 0", "result": {
        "method": "ce", "estimate": 0.0, "ci95": [0.0, float("nan")], "runs": 100,
        "plain_mc_same_runs": {"ci95": [0.0, 0.036]}, "plain_runs_same_precision": float("nan"),
        "runs_ratio": float("nan")}}
    text = "\n".join(estimate_lines(data))
    assert "nan" not in text.lower() and "no failing run among 100" in text
    data["result"].update(estimate=1e-3, ci95=[float("nan"), float("nan")])
    assert "nan" not in "\n".join(estimate_lines(data)).lower()


def test_small_budget_at_the_minimum_runs_and_prints_no_nan(tmp_path: Path) -> None:
    from corridor.estimate import estimate_lines

    data = estimate(GAUSS, "nmac > 0", method="ce", budget=100, out=tmp_path / "ce", executor="inline",
                    report=False)
    assert data["result"]["runs"] == 100
    assert "nan" not in "\n".join(estimate_lines(data)).lower()


@pytest.mark.parametrize("kw,needle", [
    ({"runs": "3"}, "runs must be a whole number"), ({"seed": "7"}, "seed must be a whole number"),
    ({"sets": 5}, "sets must be a list of strings"), ({"runs": 2.5}, "runs must be a whole number"),
    ({"seed": 1.5}, "seed must be a whole number"), ({"sets": "duration=0.2"}, "sets must be a list"),
    ({"executor": "bogus"}, "executor 'bogus'"), ({"variants": ["nosuch"]}, "--variant 'nosuch'"),
    ({"rerun": "x.rrd", "rerun_run": "bogus"}, "--rerun-run 'bogus'"), ({"workers": 0}, "workers must be >= 1"),
])
def test_python_api_validates_like_the_cli(kw: dict, needle: str, tmp_path: Path) -> None:
    out = tmp_path / "o"
    with pytest.raises(CorridorError) as exc:
        run(GAUSS, out=out, **kw)
    assert needle in str(exc.value) and len(str(exc.value).splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("kw", [{"budget": "100"}, {"seed": 1.5}, {"sets": "x=1"}, {"executor": "bogus"}])
def test_python_rare_api_validates(kw: dict, tmp_path: Path) -> None:
    args = {"budget": 100, **kw}
    with pytest.raises(CorridorError):
        estimate(GAUSS, "nmac > 0", out=tmp_path / "e", **args)
    with pytest.raises(CorridorError):
        falsify(GAUSS, "separation", out=tmp_path / "f", **args)
    assert not (tmp_path / "e").exists() and not (tmp_path / "f").exists()


def test_controller_typo_in_a_sweep_variant_fails_at_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sc = tmp_path / "typo.yaml"
    sc.write_text(f"extends: {GAUSS}\nsweep:\n  good: {{}}\n  bad: {{monitors.sep.type: uav_separaton}}\n")
    assert main([str(sc), "--out", str(tmp_path / "o"), "--quiet", "--variant", "good"]) == 2
    err = _one_line(capsys)
    assert "sweep.bad" in err and "uav_separaton" in err and "did you mean 'uav_separation'" in err, err
    assert not (tmp_path / "o").exists()


def test_set_wins_over_the_variant(tmp_path: Path) -> None:
    """The variant puts UAV a 5 km away; --set puts it back at x = 0 beside b (x ~ N(0, 10 m)): the
    command line wins, for the batch and the estimate."""
    sc = tmp_path / "far.yaml"
    sc.write_text(f"extends: {GAUSS}\nsweep:\n  far: {{backends.sim.params.vehicles.a.x_m: 5000}}\n")
    far = run(sc, out=tmp_path / "a", report=False, workers=1).rows
    assert far.loc[0, "sep_min_h_m"] > 4000
    near = run(sc, out=tmp_path / "b", report=False, workers=1,
               sets=["backends.sim.params.vehicles.a.x_m=0"]).rows
    assert near.loc[0, "sep_min_h_m"] < 100


def test_summary_counts_runs_without_a_value() -> None:
    """min_ttc_s is NaN in a run without a closing pair: the mean is over the others, and the cell
    says how many runs had a value."""
    import pandas as pd

    from corridor.summary import summary_rows

    df = pd.DataFrame({"variant": ["a"] * 3, "status": ["ok"] * 3, "min_ttc_s": [2.0, float("nan"), 4.0]})
    head, rows = summary_rows(df, ["min_ttc_s"], collisions=False)
    assert rows[0][head.index("min_ttc_s")] == "3 ± 1.41 (2/3)"


def test_report_section_of_an_estimate_without_failures_has_no_nan_bound() -> None:
    from corridor.analysis.rare.section import estimate_section

    data = {"event": "nmac > 0", "likely_failures": [], "result": {
        "method": "ce", "estimate": 0.0, "ci95": [0.0, float("nan")], "runs": 100,
        "plain_mc_same_runs": {"ci95": [0.0, 0.036]}, "plain_runs_same_precision": float("nan"),
        "runs_ratio": float("nan")}}
    text = estimate_section(data)
    assert "[0, -]" not in text and "nan" not in text.lower()
    assert "none: no failing run" in text and "no failing run among 100" in text


def test_ray_missing_is_refused_before_the_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # as without the [ray] extra: `import ray` fails
    out = tmp_path / "o"
    with pytest.raises(CorridorError, match="needs Ray"):
        run(GAUSS, out=out, executor="ray")
    assert not out.exists()
