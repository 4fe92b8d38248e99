"""tools/compare_rows.py leaves out exactly the columns that measure the machine (wall-clock and CPU
timings), and compares every column the simulation decides, durations in simulated seconds too."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("compare_rows", ROOT / "tools" / "compare_rows.py")
compare_rows = importlib.util.module_from_spec(spec)
sys.modules["compare_rows"] = compare_rows
spec.loader.exec_module(compare_rows)

# timings of the machine, as the components name them (docs/reference/metrics.md)
MACHINE = ["wall_s", "rtf", "wall_per_sim_s", "cpu_per_sim_s", "mpc_cpu_capped", "solve_p50_ms", "solve_p95_ms",
           "solve_max_ms", "mpc_solve_p50_s", "mpc_solve_p95_s", "tube_solve_ms_mean", "plan_time_p50_s",
           "plan_time_p95_s", "plan_time_max_s", "plan_search_s", "plan_optimise_s", "traceback"]
# decided by the simulation (simulated seconds, counts, drawn parameters)
SIMULATION = ["manoeuvre_time_s", "completion_time_s", "draw.backends.air.params.encounter.piloted_time_s",
              "mpc_solves", "tube_solver_failures", "time_to_goal_mean_s", "min_ttc_s"]


def _rows(path: Path, columns: list[str], value: float) -> Path:
    df = pd.DataFrame({"scenario_file": ["parking_lot.yaml"], "run_id": ["default-s0"],
                       **{c: [value] for c in columns}})
    df.to_parquet(path, index=False)
    return path


def test_machine_timings_are_left_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = _rows(tmp_path / "a.parquet", MACHINE + SIMULATION, 1.0)
    after = pd.read_parquet(before)
    after[MACHINE] = 2.0  # another machine, another load: only the timings move
    after.to_parquet(tmp_path / "b.parquet", index=False)
    assert compare_rows.diff(before, tmp_path / "b.parquet", {}) == 0
    assert f"{len(SIMULATION)} columns compared, 0 differences" in capsys.readouterr().out


@pytest.mark.parametrize("column", SIMULATION)
def test_a_simulated_column_that_changes_is_a_difference(tmp_path: Path, column: str,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    before = _rows(tmp_path / "a.parquet", MACHINE + SIMULATION, 1.0)
    after = pd.read_parquet(before)
    after[column] = 1.5
    after.to_parquet(tmp_path / "b.parquet", index=False)
    assert compare_rows.diff(before, tmp_path / "b.parquet", {}) == 1
    assert f"column {column!r} differs in 1 runs" in capsys.readouterr().out


def test_options_and_scenarios_in_any_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``record OUT --seeds 3 a.yaml b.yaml`` (options before the scenario files) was refused with
    "unrecognized arguments"."""
    calls = []
    monkeypatch.setattr(compare_rows, "record", lambda *a: calls.append(a))
    out = tmp_path / "rows.parquet"
    assert compare_rows.main(["record", str(out), "--seeds", "3", "a.yaml", "--duration", "300", "b.yaml"]) == 0
    assert compare_rows.main(["record", str(out), "a.yaml", "b.yaml", "--seeds", "3", "--duration", "300"]) == 0
    assert calls == [(out, 3, 300.0, [Path("a.yaml"), Path("b.yaml")])] * 2
    before = _rows(tmp_path / "a.parquet", SIMULATION, 1.0)
    assert compare_rows.main(["diff", str(before), "--rename", "x=y", str(before)]) == 0
    with pytest.raises(SystemExit) as e:
        compare_rows.main(["record", str(out), "--seeds", "three"])
    assert e.value.code == 2


def test_a_last_bit_difference_is_named_and_fails_with_exact(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Within 1e-9 relative is "no difference" by default, but the summary names the column, and
    ``--exact`` (bit for bit) reports it: a refactor claimed row-identical must pass with ``--exact``."""
    before = _rows(tmp_path / "a.parquet", SIMULATION, 1.0)
    after = pd.read_parquet(before)
    after["min_ttc_s"] = 1.0 + 2.0**-52  # the next float after 1.0
    after.to_parquet(tmp_path / "b.parquet", index=False)
    assert compare_rows.diff(before, tmp_path / "b.parquet", {}) == 0
    assert "1 equal only within 1e-9 relative: min_ttc_s" in capsys.readouterr().out
    assert compare_rows.main(["diff", str(before), str(tmp_path / "b.parquet"), "--exact"]) == 1
    assert "column 'min_ttc_s' differs in 1 runs" in capsys.readouterr().out
    assert compare_rows.main(["diff", str(before), str(before), "--exact"]) == 0
    assert "every compared column equal bit for bit" in capsys.readouterr().out
