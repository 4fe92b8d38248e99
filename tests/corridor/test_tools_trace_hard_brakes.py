"""tools/trace_hard_brakes.py: every hard-brake onset the surrogate-safety monitor counts is found and
attributed to the term of the merging controller's command that caused it (diagnosis of issue 27)."""

from __future__ import annotations

import importlib.util
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("trace_hard_brakes", ROOT / "tools" / "trace_hard_brakes.py")
thb = importlib.util.module_from_spec(spec)
sys.modules["trace_hard_brakes"] = thb
spec.loader.exec_module(thb)


def _trace(variant: str, seed: int, duration_s: float, out: Path) -> dict:
    """The tool's run, in a spawned process (libsumo: one simulation per process)."""
    return thb.trace(variant, seed, duration_s, out)


def _rec(**kw: object) -> dict:
    return {"commanded": True, "ha_mode": "open", **kw}


def test_the_binding_term_of_a_command_is_named() -> None:
    # the safety layer against the virtual leader braked below the gap rule's -3 m/s²
    assert thb.cause(_rec(gap_in=2.0, gap_rule=-3.0, gap_out=-6.0, cap_in=-6.0, cap_out=-6.0, a_sent=-6.0)) == (
        "safety layer: virtual leader", "open")
    # the own-leader cap lowered it further
    assert thb.cause(_rec(gap_in=2.0, gap_rule=-3.0, gap_out=-3.0, cap_in=-3.0, cap_out=-6.0, a_sent=-6.0))[0] == \
        "safety layer: own leader"
    # a comfortable command that the speed clip turned into a jump (early opening: mode "free")
    assert thb.cause(_rec(ha_mode="free", pre_open=-0.5, cap_in=-0.5, cap_out=-0.5, a_sent=-15.0)) == (
        "speed command clipped to v_max", "free/pre-opening")
    # a comfortable command executed harder by SUMO
    assert thb.cause(_rec(cap_in=-1.0, cap_out=-1.0, a_sent=-1.0))[0] == "SUMO braked harder than commanded"
    # not commanded at that tick: the caller looks at fallbacks, releases and leaders
    assert thb.cause({"road": "main"}) == ("", "")
    assert thb.cause(None) == ("", "")


def test_every_onset_of_a_run_is_attributed(tmp_path: Path) -> None:
    """make run's v2x_fifo, seed 0, 300 s: the run counts 1 hard brake; the tracer finds it, from the
    safety layer behind a ramp predecessor that had just become the car's predecessor. (Before the speed
    clip's fix, 1649b91, a second one came from the 30 m/s clip of a comfortable early-opening command.)"""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        r = pool.submit(_trace, "v2x_fifo", 0, 300.0, tmp_path).result()
    assert r["onsets"] == r["hard_brakes"] == 1
    assert r["by_cause"] == {"safety layer: virtual leader": 1}
    rows = [json.loads(line) for line in (tmp_path / "v2x_fifo-s0.jsonl").read_text().splitlines()]
    layer = next(x for x in rows if x["cause"].startswith("safety layer"))
    assert layer["pred_road"] == "ramp" and layer["pred_changed_s_ago"] <= 1.0
