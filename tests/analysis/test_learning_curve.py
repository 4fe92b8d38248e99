"""The learning-curve figure of --learn folders: one line per method, the interval band, held-out marks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from corridor.analysis.learning_curve import figure, main


def _folder(tmp: Path, method: str, means: list[float]) -> Path:
    d = tmp / method
    d.mkdir()
    curve = [{"stage": i, "runs": 8, "objective_mean": m, "objective_ci95": [m - 0.1, m + 0.1], "violating_runs": i % 2}
             for i, m in enumerate(means)]
    hold = {"runs": 20, "hand_tuned": {"objective_mean": -1.2}, "learned": {"objective_mean": -1.1}}
    (d / "learn.json").write_text(json.dumps({"method": method, "scenario": "uav_encounter", "variant": "pf",
                                              "objective": "-path_ratio_mean", "curve": curve, "holdout": hold,
                                              "keys": ["controllers.avoid.params.boundaries.avoid_enter.dist_m"]}))
    return d


def test_curves_per_method_at_cumulative_runs(tmp_path: Path) -> None:
    fig = figure([_folder(tmp_path, "blrl", [-1.3, -1.2, -1.1]), _folder(tmp_path, "cma", [-1.25, -1.15])])
    ax, ax2 = fig.axes
    lines = [ln for ln in ax.get_lines() if "training" in ln.get_label()]
    assert [ln.get_label() for ln in lines] == ["blrl (training stages)", "cma (training stages)"]
    np.testing.assert_array_equal(lines[0].get_xdata(), [8, 16, 24])
    np.testing.assert_array_equal(lines[1].get_ydata(), [-1.25, -1.15])
    assert sum("held-out" in ln.get_label() for ln in ax.get_lines()) == 4
    assert [p.get_height() for p in ax2.patches] == [0, 1, 0, 0, 1]


def test_held_out_rows_of_the_benchmark_are_marked_at_their_training_runs(tmp_path: Path) -> None:
    blrl, ppo = _folder(tmp_path, "blrl", [-1.3, -1.2]), _folder(tmp_path, "ppo", [-1.25, -1.15, -1.1])
    rows = [{"folder": str(ppo), "training_episodes": 24, "learned_objective": [-1.0, -1.1, -0.9], "pairs": 200,
             "violating_learned": 11, "hand_tuned_objective": [-1.34, -1.35, -1.33], "violating_hand_tuned": 0}]
    ax = figure([blrl, ppo], rows).axes[0]
    (mark,) = ax.containers  # one errorbar: the ppo folder's row; blrl has none
    assert mark.get_label() == "ppo: held-out (200 seeds, 11 runs breaking a constraint)"
    np.testing.assert_array_equal(mark.lines[0].get_xdata(), [24])
    np.testing.assert_array_equal(mark.lines[0].get_ydata(), [-1.0])
    (hand,) = [ln for ln in ax.get_lines() if ln.get_label().startswith("hand-tuned")]
    np.testing.assert_array_equal(hand.get_ydata(), [-1.34, -1.34])
    table, svg = tmp_path / "bench.json", tmp_path / "curves.svg"
    table.write_text(json.dumps(rows))
    assert main([str(blrl), str(ppo), "--held-out", str(table), "--out", str(svg)]) == 0
    assert "11 runs breaking a constraint" in svg.read_text()
    assert main([str(blrl), "--held-out", str(tmp_path / "none.json"), "--out", str(svg)]) == 2


def test_a_folder_without_learn_json_is_exit_2(tmp_path: Path) -> None:
    assert main([str(tmp_path)]) == 2


def test_a_stage_of_few_runs_does_not_flatten_the_curves(tmp_path: Path) -> None:
    """A stage whose t interval is 100 times the curve's range (two runs) runs off the axis: the y-axis spans
    the means and the held-out marks with a margin."""
    d = _folder(tmp_path, "ppo", [-1.3, -1.2, -1.1, -1.25])
    data = json.loads((d / "learn.json").read_text())
    data["curve"][2]["objective_ci95"] = [-60.0, 58.0]
    (d / "learn.json").write_text(json.dumps(data))
    lo, hi = figure([d]).axes[0].get_ylim()
    assert -1.45 <= lo < -1.3 and -1.1 < hi <= -0.95  # means -1.3..-1.1, marks -1.2 / -1.1: half the range, 0.1
