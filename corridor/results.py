"""The results store: one Parquet part per finished run (written at once, atomically), compacted
into ``runs.parquet``.  A killed batch loses no finished run; ``--resume`` skips them.  The store never
deletes anything: what a folder may hold and when it may be replaced is ``corridor.batchdir``'s rule."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

FIRST_COLUMNS = ["run_id", "scenario", "variant", "seed", "status", "error", "wall_s", "sim_s", "collisions"]


class ResultStore:
    def __init__(self, out_dir: str | Path) -> None:
        self.dir = Path(out_dir)
        self.parts = self.dir / "parts"
        self.parts.mkdir(parents=True, exist_ok=True)
        # the rows this store wrote, as one table while they share one schema (see read)
        self._acc: pa.Table | None = None
        self._acc_new: list[pa.Table] = []  # written since the last combine
        self._acc_ids: set[str] = set()
        self._acc_ok = True  # False once a row's schema differed or a run id was written twice
        for tmp in self.parts.glob(".*.tmp"):  # a part whose write was cut off (killed, disk full)
            tmp.unlink()
        if (self.dir / "runs.parquet").exists():
            self._explode(pd.read_parquet(self.dir / "runs.parquet", partitioning=None))

    def _explode(self, df: pd.DataFrame) -> None:
        """Turn a compacted table back into parts, so a resumed batch appends to it."""
        for rec in df.to_dict("records"):
            if not (self.parts / f"{rec['run_id']}.parquet").exists():
                self.write(rec)

    def write(self, row: dict[str, Any]) -> None:
        row = {k: (json.dumps(v) if isinstance(v, dict | list) else v) for k, v in row.items()}
        tmp = self.parts / f".{row['run_id']}.tmp"
        try:
            # pyarrow directly: a third of pandas' cost for one row (the batch process writes every
            # row itself); read back, the part is the same one-row frame (tests/corridor/test_kernel_results_store.py)
            try:
                table = pa.Table.from_pylist([row])
            except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
                table = pa.Table.from_pandas(pd.DataFrame([row]), preserve_index=False)  # pandas' own conversion
            pq.write_table(table, tmp)
            os.replace(tmp, self.parts / f"{row['run_id']}.parquet")
        except BaseException:
            tmp.unlink(missing_ok=True)  # never leave a partial part behind
            raise
        self._remember(str(row["run_id"]), table)

    def _remember(self, run_id: str, table: pa.Table) -> None:
        """Keep the written row for ``read``: appended to one table of contiguous columns (a one-row
        table of 140 columns holds ~140 kB of Arrow objects: 10,000 of them would be 1.4 GB), as long
        as every row has the same schema and no run id comes twice; else ``read`` reads the parts."""
        if not self._acc_ok:
            return
        first = self._acc if self._acc is not None else (self._acc_new[0] if self._acc_new else table)
        if run_id in self._acc_ids or table.schema.metadata or not table.schema.equals(first.schema):
            self._acc_ok, self._acc, self._acc_new, self._acc_ids = False, None, [], set()
            return
        self._acc_ids.add(run_id)
        self._acc_new.append(table)
        if len(self._acc_new) >= 64:
            self._combine()

    def _combine(self) -> pa.Table | None:
        if self._acc_new:
            self._acc = pa.concat_tables([t for t in (self._acc, *self._acc_new) if t is not None]).combine_chunks()
            self._acc_new = []
        return self._acc

    def finished(self) -> set[str]:
        """Run ids with an ``ok`` row (errored runs are tried again on resume)."""
        done = set()
        for p in self.parts.glob("*.parquet"):
            if pd.read_parquet(p, columns=["status"], partitioning=None)["status"].iloc[0] == "ok":
                done.add(p.stem)
        return done

    def read(self) -> pd.DataFrame:
        """Every part, in file-name order: the frame pandas' concatenation of the parts gives
        (tests/corridor/test_kernel_results_store.py).  The rows this store wrote come from memory
        (reading a part back costs ~2-5 ms of the batch process's time after the last run) when
        they and the parts read from disk share one schema (a batch's ok rows, usually): one Arrow
        table, one conversion.  Otherwise each part is converted and pandas joins them (its own type
        promotion: [None, 0] stays object)."""
        files = sorted(self.parts.glob("*.parquet"))
        if not files:
            return pd.DataFrame(columns=FIRST_COLUMNS)
        acc = self._combine() if self._acc_ok else None
        if acc is not None:
            others = [f for f in files if f.stem not in self._acc_ids]
            disk = [pq.read_table(f, partitioning=None) for f in others]
            if all(t.schema.equals(acc.schema, check_metadata=True) for t in disk):
                names = [f.name for f in others] + [f"{r}.parquet" for r in acc.column("run_id").to_pylist()]
                order = sorted(range(len(names)), key=names.__getitem__)
                return pa.concat_tables([*disk, acc]).take(order).to_pandas()
        return pd.concat([pq.read_table(f, partitioning=None).to_pandas() for f in files], ignore_index=True)

    def compact(self, order: Callable[[str], int] | list[str]) -> pd.DataFrame:
        """Write ``runs.parquet`` with the rows in batch order (``order``: run ids, or a rank function)."""
        df = self.read()
        if not callable(order):
            rank = {rid: i for i, rid in enumerate(order)}
            order = lambda r: rank.get(r, len(rank))  # noqa: E731
        df = df.assign(_o=df["run_id"].map(order)).sort_values("_o", kind="stable").drop(columns="_o")
        cols = [c for c in FIRST_COLUMNS if c in df.columns] + [c for c in df.columns if c not in FIRST_COLUMNS]
        df = df[cols].reset_index(drop=True)
        tmp = self.dir / ".runs.parquet.tmp"
        df.to_parquet(tmp, index=False)
        os.replace(tmp, self.dir / "runs.parquet")
        return df
