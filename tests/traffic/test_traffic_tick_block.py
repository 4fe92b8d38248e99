"""The road monitors process ticks in blocks (``corridor.analysis.monitoring.tick_block``); any block size gives
the figures of tick-by-tick processing, bit for bit."""

from __future__ import annotations

import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from corridor.analysis.monitoring.tick_block import TickBlock
from corridor.snapshot import RoadFrame, RoadTables, WorldSnapshot
from tests.conftest import KRAUSS, SCENARIOS

SCENARIO = SCENARIOS / "merging.yaml"


def _snapshot(uids: list[int], xs: list[float], offset: int = 0) -> WorldSnapshot:
    """``offset`` rows of another backend (x = -1) before the road's rows."""
    n = offset + len(uids)
    pos = np.zeros((n, 3))
    pos[:, 0] = [-1.0] * offset + xs
    road = RoadFrame("road", RoadTables(), uid=np.array(uids, dtype=np.int64), offset=offset)
    return WorldSnapshot(ids=np.array([f"v{k}" for k in range(n)], dtype=object), kind=np.zeros(n, np.int8),
                         role=np.zeros(n, np.int8), position=pos, velocity=np.zeros((n, 3)), heading=np.zeros(n),
                         size=np.ones((n, 3)), road=road)


def test_a_block_concatenates_the_road_rows_of_its_ticks() -> None:
    block = TickBlock(3)
    assert block.take() is None
    assert not block.add(0.1, _snapshot([5, 6], [1.0, 2.0]))
    assert not block.add(0.2, _snapshot([], []))
    assert block.add(0.3, _snapshot([7, 5, 6], [3.0, 4.0, 5.0], offset=2))  # full after 3 ticks
    b = block.take()
    assert len(b) == 3 and b.t.tolist() == [0.1, 0.2, 0.3]
    assert b.rows.tolist() == [2, 0, 3] and b.starts.tolist() == [0, 2, 2]
    assert b.tick.tolist() == [0, 0, 2, 2, 2]
    assert b.road("uid").tolist() == [5, 6, 7, 5, 6]
    assert b.rows_of("position")[:, 0].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]  # the road's rows only
    assert block.take() is None  # emptied
    with pytest.raises(ValueError, match="block size"):
        TickBlock(0)


def _monitors_with_blocks(ticks: int) -> dict[str, object]:
    from corridor.analysis.monitoring.merge_loops import MergeLoops
    from corridor.analysis.monitoring.road import SurrogateSafety, TrafficKpis
    from corridor.run import build
    from corridor.scenario import load

    SurrogateSafety.block_ticks = TrafficKpis.block_ticks = MergeLoops.block_ticks = ticks
    # warm-up inside a block; a TTC threshold that is crossed (time exposed > 0) in 80 s; loop intervals
    # of 10 s (some inside a block), free-flow speed over the first 30 s
    sets = ["duration=80", "warmup=23.3", "monitors.ssm.params.ttc_threshold_s=12", *KRAUSS,
            "monitors.loops.params.interval_s=10", "monitors.loops.params.free_flow_window_s=30",
            "monitors.loops.params.sustain_s=10", "monitors.loops.params.window_s=20",
            "monitors.loops.params.transition_s=0"]
    sc, _ = load(str(SCENARIO), sets)
    sim = build(sc, 2, Path(tempfile.mkdtemp()))
    metrics = sim.run()
    loops = [f"loop_{q}_{st}" for q in ("flow_vph", "speed_mps", "density_vpkm") for st in ("up", "merge", "down")]
    signals = {n: sim.ctx.signals.get(n) for n in ("min_ttc", "vehicles", "mean_speed", *loops)}
    return {"metrics": metrics, "signals": signals}


def test_blocks_of_1_and_of_37_ticks_give_the_same_figures_bit_for_bit() -> None:
    out = []
    for ticks in (1, 37):
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
            out.append(pool.submit(_monitors_with_blocks, ticks).result())  # libsumo: one per process
    one, many = out
    m = one["metrics"]
    assert m["hard_brakes"] > 0 and m["ttc_exposed_s"] > 0 and m["throughput_vph"] > 0  # all exercised
    assert m["merge_loss_mean_s"] > 0 and np.isfinite(m["energy_proxy_mean"])
    for key in ("min_ttc_s", "max_drac_mps2", "ttc_exposed_s", "hard_brakes", "throughput_vph", "tts_vh",
                "energy_proxy_mean", "merge_loss_mainline_s", "merge_loss_ramp_s", "merge_loss_mean_s"):
        assert many["metrics"][key] == m[key], key
    for key in ("free_flow_speed_mps", "breakdown", "breakdown_s", "prebreakdown_flow_vph", "discharge_flow_vph",
                "capacity_drop_pct"):  # the loops' figures (NaN where there is no breakdown)
        assert np.array_equal(many["metrics"][key], m[key], equal_nan=True), key
    flows = one["signals"]["loop_flow_vph_down"]
    assert len(flows[0]) == 8 and flows[1].sum() > 0  # eight 10 s intervals, vehicles counted
    assert len(one["signals"]["min_ttc"][0]) == 800  # one value per tick (the others: ticks with vehicles)
    for name, (t, v) in one["signals"].items():
        assert (len(t) > 700 or name.startswith("loop_")) and np.array_equal(many["signals"][name][0], t), name
        assert np.array_equal(many["signals"][name][1], v, equal_nan=True), name
