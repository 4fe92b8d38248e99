"""The TPCAP entry point and the independent checker, as a user runs them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from corridor.controllers.parking import check as checker
from corridor.controllers.parking import tpcap
from corridor.controllers.parking.case import Case, CaseError, format_case, parse_case, read_case
from tests.conftest import TEST_DATA
from tests.controllers import tpcap_cases as tc

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
    assert tpcap.main([str(path), "--out", str(tmp_path / "t.csv")]) == 1
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


# ---------------------------------------------------------------- precision far from the origin
def test_a_case_at_1e9_m_round_trips_through_the_csv(tmp_path: Path) -> None:
    """The written trajectory starts exactly at the case's start and ends at its goal when the case
    sits 1e9 m from the origin (with %.10g the centimetres were lost), and the checker passes it."""
    case = tc.shifted(read_case(DATA / "Case17.csv"), 1e9 + 0.3125, -1e9 + 0.7)
    path, out = tmp_path / "far.csv", tmp_path / "traj.csv"
    path.write_text(format_case(case))
    assert tpcap.main([str(path), "--out", str(out)]) == 0
    rows = checker.read_trajectory(out)
    again = read_case(path)
    assert (rows[0, 1], rows[0, 2], rows[0, 3]) == again.start  # repr-exact: bit for bit
    assert np.hypot(rows[-1, 1] - again.goal[0], rows[-1, 2] - again.goal[1]) < 1e-6
    assert checker.main([str(path), str(out)]) == 0


def test_the_csv_writes_repr_exact_floats() -> None:
    rows = np.array([[0.1, 1e9 + 0.123456789, -1e9 - 1 / 3, np.pi, -2.5, 1e-17, 0.0]])
    line = tpcap.format_csv(rows).splitlines()[1]
    assert np.array_equal(np.array([float(v) for v in line.split(",")]), rows[0])


def test_goal_equal_to_start_writes_one_row(tmp_path: Path) -> None:
    base = read_case(DATA / "Case1.csv")
    path, out = tmp_path / "same.csv", tmp_path / "traj.csv"
    path.write_text(format_case(Case(start=base.start, goal=base.start, obstacles=base.obstacles)))
    assert tpcap.main([str(path), "--out", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 2
    assert checker.main([str(path), str(out)]) == 0


# ---------------------------------------------------------------- bad options: one line, exit 2, before planning
def _no_planning(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*a: object, **k: object) -> None:
        raise AssertionError("planned before checking the options")
    monkeypatch.setattr(tpcap, "plan", refuse)


@pytest.mark.parametrize("option, value", [
    ("--out", "{tmp}"),  # a folder
    ("--out", "{tmp}/missing/traj.csv"),  # a missing parent
    ("--out", ""),  # empty
    ("--out", "/sys/kernel/corridor-traj.csv"),  # not writable, even by root
    ("--plot", "{tmp}/missing/case.png"),  # a missing folder
])
def test_unwritable_outputs_are_refused_before_planning(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture, option: str, value: str) -> None:
    _no_planning(monkeypatch)
    argv = [str(DATA / "Case1.csv"), "--out", str(tmp_path / "t.csv")]
    argv += [option, value.format(tmp=tmp_path)]
    assert tpcap.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: " + option) and "\n" not in err
    assert not (tmp_path / "t.csv").exists()


def test_a_full_disk_is_one_line_exit_2(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "corridor.controllers.parking.tpcap", str(DATA / "Case17.csv"),
                          "--out", "/dev/full"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and res.stderr.strip().startswith("error: --out /dev/full")
    assert len(res.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("dt", ["1e-9", "0", "nan", "0.2"])
def test_output_step_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
                                dt: str) -> None:
    _no_planning(monkeypatch)
    assert tpcap.main([str(DATA / "Case1.csv"), "--out", str(tmp_path / "t.csv"), "--dt", dt]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --dt") and "\n" not in err


# ---------------------------------------------------------------- huge extents and inputs: a named bound, exit 2
def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "corridor.controllers.parking.tpcap", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("text, bound", [
    ("0,0,0,8,0,0,1,4,5000,5000,5001,5000,5001,5001,5000,5001", "MAX_GRID_CELLS"),  # an obstacle 5 km away
    ("0,0,0,100000,0,0,0", "MAX_GRID_CELLS"),  # the goal 100 km away
])
def test_a_case_needing_a_huge_grid_names_the_bound(tmp_path: Path, text: str, bound: str) -> None:
    path = tmp_path / "case.csv"
    path.write_text(text)
    res = _run([str(path), "--out", str(tmp_path / "t.csv")])
    assert res.returncode == 2 and bound in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_a_million_tiny_obstacles_name_the_bound(tmp_path: Path) -> None:
    n = 1_000_000
    xy = np.arange(n) % 1000 * 0.5 + 20.0, np.arange(n) // 1000 * 0.5 + 20.0
    square = np.column_stack([xy[0], xy[1], xy[0] + 0.1, xy[1], xy[0] + 0.1, xy[1] + 0.1, xy[0], xy[1] + 0.1])
    path = tmp_path / "million.csv"
    with open(path, "w") as fh:
        fh.write(f"0,0,0,8,0,0,{n},")
        fh.write(",".join(["4"] * n) + ",")
        np.savetxt(fh, square.reshape(1, -1), fmt="%.1f", delimiter=",")
    res = _run([str(path), "--out", str(tmp_path / "t.csv")])
    assert res.returncode == 2 and "MAX_CASE_BYTES" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    with pytest.raises(CaseError, match="MAX_OBSTACLES"):
        parse_case(f"0,0,0,8,0,0,{n}," + ",".join(["4"] * n) + ",0" * (8 * n))


def test_dev_zero_as_the_case_names_the_bound(tmp_path: Path) -> None:
    res = _run(["/dev/zero", "--out", str(tmp_path / "t.csv")])
    assert res.returncode == 2 and "MAX_CASE_BYTES" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_ten_thousand_obstacles_beside_a_free_path_plan_or_say_why(tmp_path: Path) -> None:
    """10^4 small obstacles in a field beside a free 30 m straight road: a trajectory (checked), or
    exit 1 with a reason that is not empty."""
    ii, jj = np.meshgrid(np.arange(200), np.arange(50), indexing="ij")
    x0, y0 = ii.ravel() * 0.2 - 5.0, jj.ravel() * 0.2 + 4.0  # 40 m x 10 m, 4 m left of the road's centre
    polys = [np.array([[x, y], [x + 0.05, y], [x + 0.05, y + 0.05], [x, y + 0.05]]) for x, y in zip(x0, y0)]
    case = Case(start=(0.0, 0.0, 0.0), goal=(25.0, 0.0, 0.0), obstacles=tuple(polys))
    path, out = tmp_path / "field.csv", tmp_path / "t.csv"
    path.write_text(format_case(case))
    res = _run([str(path), "--out", str(out)])
    if res.returncode == 1:
        reason = res.stdout.strip().removeprefix("no trajectory:").strip()
        assert reason and "()" not in reason
    else:
        assert res.returncode == 0, res.stderr
        assert checker.main([str(path), str(out)]) == 0
