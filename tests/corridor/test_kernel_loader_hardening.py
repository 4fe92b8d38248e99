"""Loader hardening (issue 18): hostile or broken input gives one line ``FILE: field.path: what is
wrong`` (a ``ScenarioError``, exit 2 from the CLI), never a traceback, a hang, or file content."""

from __future__ import annotations

from pathlib import Path

from corridor.cli import main

ROOT = Path(__file__).resolve().parents[2]
MERGING = ROOT / "scenarios" / "merging.yaml"


def run_cli(capsys, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    return code, capsys.readouterr().err.strip()


def assert_one_line(code: int, err: str, *needles: str, max_len: int = 300) -> None:
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert len(err) < max_len, err
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
    from corridor.cli import resolve_scenario

    assert resolve_scenario("merging") == MERGING
