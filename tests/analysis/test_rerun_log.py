"""The Rerun recording of a real (short) merging run: every signal sample is logged, the last partial
block of a block-processing monitor included; a ground grid at the origin; aircraft markers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from corridor.run import build
from corridor.scenario import load
from tests.conftest import SCENARIOS


def _times(rrd: Path, entity: str) -> np.ndarray:
    """The ``sim_time`` stamps [s] of every row logged at ``entity``."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == entity and "sim_time" in chunk.timeline_names:
            col = chunk.to_record_batch().column("sim_time")
            out.append(pa.compute.cast(col, pa.int64()).to_numpy(zero_copy_only=False) / 1e9)
    return np.sort(np.concatenate(out)) if out else np.zeros(0)


def test_last_partial_block_of_signals_is_recorded(tmp_path: Path) -> None:
    sc, _ = load(SCENARIOS / "merging.yaml", ["duration=12", "warmup=0"])
    rrd = tmp_path / "m.rrd"
    sim = build(sc, 0, tmp_path, rerun_path=str(rrd), run_id="sumo_default-s0")
    sim.run()
    t_sig, x = sim.ctx.signals.get("min_ttc")  # 100-tick blocks: 10 s processed in a tick, 2 s at the end
    assert t_sig[-1] > 11.9
    t_sig = t_sig[np.isfinite(x)]  # +inf (no closing pair) is not drawn in Rerun
    t_rec = _times(rrd, "/metrics/min_ttc")
    assert len(t_rec) == len(t_sig) and abs(t_rec[-1] - t_sig[-1]) < 1e-6
    from rerun.chunk import RrdReader

    paths = {c.entity_path for c in RrdReader(rrd).stream()}
    assert {"/world/ground", "/world/origin"} <= paths
