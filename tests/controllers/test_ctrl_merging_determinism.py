"""V2X merging is deterministic: the same seed gives the same row, whichever process runs it (the
channel's draws, the compiled Kalman fuse of the tracks, the coordinator), and two seeds differ."""

from __future__ import annotations

import tempfile

import pandas as pd

from corridor.baseline import short_overrides
from corridor.batch import expand, run_batch
from corridor.results import ResultStore
from corridor.scenario import load
from tests.conftest import SCENARIOS

VOLATILE = ("wall_s", "rtf", "cpu")


def _rows(workers: int) -> pd.DataFrame:
    path = SCENARIOS / "merging.yaml"
    sc, _ = load(path)
    sc, raw = load(path, short_overrides(sc, 60.0))
    plan = expand(sc, raw, str(path), 2, variants=["v2x_fifo", "v2x_cps"])
    with tempfile.TemporaryDirectory() as tmp:
        store = ResultStore(tmp)
        run_batch(plan, store, workers=workers, progress=False)
        df = store.compact(plan.rank)
    return df[[c for c in df.columns if not any(v in c for v in VOLATILE)]].set_index("run_id").sort_index()


def test_v2x_merging_same_seed_same_row() -> None:
    a, b = _rows(2), _rows(1)
    assert (a["status"] == "ok").all() and len(a) == 4
    assert a["v2x_sent"].min() > 100 and a["v2x_commands"].min() > 0  # the V2X path ran
    pd.testing.assert_frame_equal(a, b)
    for v in ("v2x_fifo", "v2x_cps"):  # seeds draw different traffic and losses
        assert a.loc[f"{v}-s0", "v2x_sent"] != a.loc[f"{v}-s1", "v2x_sent"]
