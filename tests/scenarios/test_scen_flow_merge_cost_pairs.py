"""``benchmarks/v2x_cost.py --scenario scenarios/flow_merge.yaml`` times every cooperative variant
against its own baseline, derived from the sweep: the variant without a controller and with the same
other overrides (connected shares aside)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from corridor.scenario import load

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import v2x_cost  # noqa: E402  (a script's folder)


def test_flow_merge_pairs() -> None:
    sc, _ = load(str(REPO / "scenarios" / "flow_merge.yaml"))
    assert v2x_cost.pairs(sc.sweep) == {
        "merge0": "human", "merge1": "human", "merge2": "human",
        "cal_merge0": "human_cal", "cal_merge1": "human_cal", "cal_merge2": "human_cal",
        "cal_all10_ramp": "human_cal", "cal_all25_ramp": "human_cal", "cal_all33_ramp": "human_cal",
        "cal_all10_lead": "human_cal", "cal_all10_lead2": "human_cal",
    }
    assert set(v2x_cost.pairs(sc.sweep, "human").values()) == {"human"}


def test_bad_variant_is_a_one_line_error() -> None:
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "v2x_cost.py"), "--scenario",
                          str(REPO / "scenarios" / "flow_merge.yaml"), "--variants", "merge9"],
                         capture_output=True, text=True, check=False)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "merge9" in out.stderr
