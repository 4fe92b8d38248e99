"""The TPCAP entry point and the independent checker, as a user runs them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from corridor.controllers.parking import check as checker
from corridor.controllers.parking import tpcap
from corridor.controllers.parking.case import format_case, parse_case, read_case
from tests.conftest import TEST_DATA

DATA = TEST_DATA / "tpcap"


def test_entry_point_writes_a_checked_trajectory_and_a_plot(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out, png = tmp_path / "traj.csv", tmp_path / "case.png"
    assert tpcap.main([str(DATA / "Case17.csv"), "--out", str(out), "--plot", str(png)]) == 0
    printed = capsys.readouterr().out
    for word in ("planning", "search", "optimisation", "manoeuvre", "length", "direction changes"):
        assert word in printed
    assert out.read_text().splitlines()[0] == "t,x,y,theta,v,a,steer"
    assert png.stat().st_size > 1000
    assert checker.main([str(DATA / "Case17.csv"), str(out)]) == 0


def test_no_trajectory_exits_1_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    case = parse_case("0,0,0,20,0,0,1,4,18,-2,24,-2,24,2,18,2")  # goal inside the block
    path = tmp_path / "blocked.csv"
    path.write_text(format_case(case))
    assert tpcap.main([str(path), "--out", str(tmp_path / "t.csv"), "--time-limit", "5"]) == 1
    out = capsys.readouterr().out.strip()
    assert out.startswith("no trajectory:") and "\n" not in out


@pytest.mark.parametrize("content", [None, "", "1,2,3", "0,0,0,5,0,0,1,4,1,1,2,2", "a,b,c,d,e,f,0",
                                     "0,0,0,5,0,0,1,2,1,1,2,2"])
def test_bad_input_exits_2_with_one_line(tmp_path: Path, content: str | None) -> None:
    path = tmp_path / "case.csv"
    if content is not None:
        path.write_text(content)
    res = subprocess.run([sys.executable, "-m", "corridor.controllers.parking.tpcap", str(path), "--out",
                          str(tmp_path / "t.csv")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr.strip().startswith("error:") and len(res.stderr.strip().splitlines()) == 1


def test_case_format_round_trips() -> None:
    case = read_case(DATA / "Case10.csv")
    again = parse_case(format_case(case))
    assert again.start == case.start and again.goal == case.goal
    for a, b in zip(again.obstacles, case.obstacles, strict=True):
        np.testing.assert_array_equal(a, b)


def straight(x0: float, x1: float, y: float = 0.0) -> np.ndarray:
    """A feasible straight drive along x at ≤ 1 m/s with a = ±1 m/s² (rows every 0.1 s)."""
    d = x1 - x0
    T = 2 * np.sqrt(d) if d <= 1 else d + 1
    t = np.linspace(0, T, int(np.ceil(T / 0.1)) + 1)
    vp = min(1.0, np.sqrt(d))
    r = vp
    s = np.where(t < r, 0.5 * t ** 2, np.where(t > T - r, d - 0.5 * (T - t) ** 2, 0.5 * r ** 2 + vp * (t - r)))
    v = np.where(t < r, t, np.where(t > T - r, T - t, vp))
    a = np.where(t < r, 1.0, np.where(t > T - r, -1.0, 0.0))
    z = np.zeros_like(t)
    return np.column_stack([t, x0 + s, z + y, z, v, a, z])


def test_checker_passes_a_clear_drive_and_catches_one_that_clips_a_polygon() -> None:
    tr = straight(0.0, 10.0)
    clear = parse_case("0,0,0,10,0,0,1,4,4,1.1,6,1.1,6,3,4,3")  # 0.129 m beside the car's left side
    assert checker.check(clear, tr) == []
    clipping = parse_case("0,0,0,10,0,0,1,4,4,0.95,6,0.95,6,3,4,3")  # 2 cm into it, only mid-way
    bad = checker.check(clipping, tr)
    assert len(bad) == 1 and bad[0].startswith("collision")


def test_checker_catches_limits_goal_and_kinematics() -> None:
    tr = straight(0.0, 10.0)
    case = parse_case("0,0,0,10,0,0,0")
    jerk = tr.copy()
    jerk[len(tr) // 2:, 6] = 0.5  # a steering step: rate 5 rad/s, and the heading does not follow
    msgs = checker.check(case, jerk)
    assert any("dsteer/dt" in m for m in msgs) and any(m.startswith("kinematics") for m in msgs)
    short = parse_case("0,0,0,10.2,0,0,0")
    assert any(m.startswith("goal") for m in checker.check(short, tr))
    fast = tr.copy()
    fast[:, 1] *= 3  # positions that need 3 m/s
    assert any("speed from positions" in m for m in checker.check(parse_case("0,0,0,30,0,0,0"), fast))


def test_checker_bad_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    bad = tmp_path / "t.csv"
    bad.write_text("t,x,y\n0,0,0\n")
    assert checker.main([str(DATA / "Case1.csv"), str(bad)]) == 2
    assert checker.main([str(DATA / "Case1.csv"), str(tmp_path / "missing.csv")]) == 2
    assert capsys.readouterr().err.count("\n") == 2
