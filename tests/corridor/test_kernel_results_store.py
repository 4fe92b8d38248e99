"""The results store writes each row's part with pyarrow directly; read back, a part must be the
same one-row frame that pandas' own writer gave (the compacted ``runs.parquet`` is built from them)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from corridor.results import ResultStore

MIXED = {
    "run_id": "v-s0", "scenario": "x", "variant": "v", "seed": 0, "status": "ok", "error": None,
    "wall_s": 1.5, "collisions": 0, "flag": True, "np_flag": np.bool_(False), "nan": math.nan,
    "ninf": -math.inf, "f64": np.float64(2.5), "i64": np.int64(7), "f32": np.float32(1.25),
    "i8": np.int8(3), "u16": np.uint16(9), "big": 2**62, "nested": {"a": [1, 2]}, "items": [1.0, 2.0],
}


def _pandas_part(row: dict, path) -> pd.DataFrame:
    """What the store wrote before: pandas' writer, same JSON encoding of dicts and lists."""
    import json
    row = {k: (json.dumps(v) if isinstance(v, dict | list) else v) for k, v in row.items()}
    pd.DataFrame([row]).to_parquet(path, index=False)
    return pd.read_parquet(path)


def test_part_reads_back_as_pandas_wrote_it(tmp_path) -> None:
    store = ResultStore(tmp_path / "out")
    store.write(MIXED)
    ours = pd.read_parquet(store.parts / "v-s0.parquet")
    pd.testing.assert_frame_equal(ours, _pandas_part(MIXED, tmp_path / "ref.parquet"))
    assert store.finished() == {"v-s0"}


# a column holds one type across a batch's rows, or None where a run did not produce it, or is
# missing from a row (an error row has no metrics); mixing types in one column fails in compact with
# either writer
MISSING = object()
columns = st.one_of(*(st.lists(st.one_of(st.none(), st.just(MISSING), s), min_size=1, max_size=6) for s in (
    st.booleans(), st.integers(-2**63, 2**63 - 1), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8))))


@settings(max_examples=80, deadline=None)
@given(values=columns)
def test_compacted_table_is_unchanged(tmp_path_factory, values) -> None:
    """Rows with a column of any scalar type: the compacted table equals the one built from
    pandas-written parts."""
    tmp = tmp_path_factory.mktemp("store")
    store = ResultStore(tmp / "out")
    rows = [{"run_id": f"r{i}", "status": "ok", **({} if v is MISSING else {"value": v})} for i, v in enumerate(values)]
    for r in rows:
        store.write(r)
    ours = store.compact([r["run_id"] for r in rows])
    ref = pd.concat([_pandas_part(r, tmp / f"{r['run_id']}.parquet") for r in rows], ignore_index=True)
    pd.testing.assert_frame_equal(ours, ref[[c for c in ours.columns]])
    # a store opened on the folder later (resume, report) reads every part from disk: the same frame
    pd.testing.assert_frame_equal(ResultStore(tmp / "out").read(), store.read())


def test_resumed_store_reads_parts_from_disk_and_memory_in_file_order(tmp_path) -> None:
    """A resumed batch: parts of an earlier session on disk, this session's rows in memory, one run
    written again (an errored run re-run): always the frame of the parts as pandas reads them."""
    out = tmp_path / "out"
    first = ResultStore(out)
    for i in (0, 2, 4, 11):
        first.write({"run_id": f"r{i}", "status": "ok", "x": float(i), "n": i})
    store = ResultStore(out)  # resumed: the first session's parts are on disk only
    for i in (1, 3, 10, 100):
        store.write({"run_id": f"r{i}", "status": "ok", "x": float(i), "n": i})

    def ref() -> pd.DataFrame:
        return pd.concat([pd.read_parquet(f) for f in sorted(store.parts.glob("*.parquet"))], ignore_index=True)

    assert store.read()["run_id"].tolist() == ["r0", "r1", "r10", "r100", "r11", "r2", "r3", "r4"]
    pd.testing.assert_frame_equal(store.read(), ref())
    store.write({"run_id": "r3", "status": "error", "x": math.nan, "n": -1})  # re-run: the part is replaced
    pd.testing.assert_frame_equal(store.read(), ref())
    assert store.read().set_index("run_id").loc["r3", "status"] == "error"


def test_a_folder_named_key_value_reopens_with_its_own_columns(tmp_path) -> None:
    """`learn_benchmark.py holdout --hand-tuned open_ahead.dist_m=0` keeps its rows in
    ``holdout/hand_tuned-open_ahead.dist_m=0``: pyarrow reads a ``key=value`` folder as a Hive partition
    and adds a column ``key`` to every table read from below it, so reopening the store (the tool's
    resume) failed on the compacted table.  The store reads a file's own columns only."""
    out = tmp_path / "holdout" / "hand_tuned-open_ahead.dist_m=0"
    first = ResultStore(out)
    for i in range(3):
        first.write({"run_id": f"r{i}", "status": "ok", "x": float(i)})
    first.compact([f"r{i}" for i in range(3)])
    again = ResultStore(out)  # resume: the compacted table is exploded back into parts
    assert again.finished() == {"r0", "r1", "r2"}
    df = again.read()
    assert df.columns.tolist() == ["run_id", "status", "x"] and df["x"].tolist() == [0.0, 1.0, 2.0]
    assert again.compact([f"r{i}" for i in range(3)]).columns.tolist() == ["run_id", "status", "x"]
