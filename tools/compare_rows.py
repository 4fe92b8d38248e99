"""Before/after proof for refactors: record the rows of every scenario (short, fixed seeds), then
compare two recordings column by column.

    python tools/compare_rows.py record before.parquet            # on the old commit
    python tools/compare_rows.py record after.parquet             # on the new commit
    python tools/compare_rows.py diff before.parquet after.parquet [--rename old=new ...]

Columns that measure the machine, not the simulation (wall time, real-time factor, solver times)
are left out of the comparison; every other column must be equal (floats to 1e-9 relative, or bit for
bit with ``diff --exact``), and a column present on one side only is reported (renames are given with
``--rename``).  The summary line says how many compared columns were equal only within the tolerance.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
# machine-dependent columns: wall-clock and CPU timings and what is derived from them (solver and
# parking-planner times, CPU-budget caps); durations in simulated seconds (manoeuvre_time_s,
# completion_time_s, a drawn *_time_s parameter) and counts (mpc_solves, tube_solver_failures) are compared
VOLATILE = re.compile(r"(^|[._])(wall|rtf|traceback)($|[._])|cpu|solve_(ms|p\d+|max|mean)"
                      r"|(^|[._])plan_(time_(p\d+|max)|search|optimise)_s$")


def record(out: Path, seeds: int, duration_s: float, scenarios: list[Path]) -> None:
    from corridor.baseline import short_overrides
    from corridor.batch import expand, run_batch
    from corridor.results import ResultStore
    from corridor.scenario import load

    frames = []
    for path in scenarios:
        sc, _ = load(path)
        sc, raw = load(path, short_overrides(sc, duration_s))
        plan = expand(sc, raw, str(path), seeds)
        with tempfile.TemporaryDirectory() as tmp:
            store = ResultStore(tmp)
            run_batch(plan, store, workers=2, progress=False)
            df = store.compact(plan.rank)
        df.insert(0, "scenario_file", path.name)
        frames.append(df)
        print(f"{path.name}: {len(df)} runs, {int((df['status'] != 'ok').sum())} errors", file=sys.stderr)
    pd.concat(frames, ignore_index=True).to_parquet(out, index=False)


def _equal(a: pd.Series, b: pd.Series, rel: float = 1e-9) -> bool:
    x, y = pd.to_numeric(a, errors="coerce"), pd.to_numeric(b, errors="coerce")
    if x.notna().equals(a.notna()) and y.notna().equals(b.notna()):
        xa, ya = x.to_numpy(dtype=float), y.to_numpy(dtype=float)
        with np.errstate(invalid="ignore"):  # inf - inf: equal infinities are caught by xa == ya
            return bool(np.all((xa == ya) | (np.isnan(xa) & np.isnan(ya)) |
                               (np.abs(xa - ya) <= rel * np.maximum(np.abs(xa), np.abs(ya)))))
    return a.astype(str).tolist() == b.astype(str).tolist()


def diff(a_path: Path, b_path: Path, renames: dict[str, str], exact: bool = False) -> int:
    a = pd.read_parquet(a_path).rename(columns=renames).set_index(["scenario_file", "run_id"]).sort_index()
    b = pd.read_parquet(b_path).set_index(["scenario_file", "run_id"]).sort_index()
    problems = []
    if list(a.index) != list(b.index):
        problems.append(f"runs differ: only before {sorted(set(a.index) - set(b.index))[:5]}, "
                        f"only after {sorted(set(b.index) - set(a.index))[:5]}")
    common = a.index.intersection(b.index)
    cols_a = {c for c in a.columns if not VOLATILE.search(c)}
    cols_b = {c for c in b.columns if not VOLATILE.search(c)}
    for c in sorted(cols_a ^ cols_b):
        side = "before" if c in cols_a else "after"
        # a column that is empty on every run of one side is no difference
        col = (a if side == "before" else b)[c]
        if col.notna().any():
            problems.append(f"column {c!r} only {side}")
    compared, inexact = 0, []
    rel = 0.0 if exact else 1e-9
    for c in sorted(cols_a & cols_b):
        x, y = a.loc[common, c], b.loc[common, c]
        compared += 1
        if _equal(x, y, rel) and not _equal(x, y, 0.0):
            inexact.append(c)
        if not _equal(x, y, rel):
            bad = [i for i in common if not _equal(x.loc[[i]], y.loc[[i]], rel)]
            problems.append(f"column {c!r} differs in {len(bad)} runs, e.g. {bad[0]}: "
                            f"{x.loc[bad[0]]!r} -> {y.loc[bad[0]]!r}")
    for p in problems:
        print(p)
    print(f"{len(common)} runs, {compared} columns compared, {len(problems)} differences"
          + (f"; {len(inexact)} equal only within 1e-9 relative: {', '.join(inexact)}" if inexact
             else "; every compared column equal bit for bit" if not problems else ""))
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="action", required=True)
    r = sub.add_parser("record")
    r.add_argument("out", type=Path)
    r.add_argument("--seeds", type=int, default=2)
    r.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run")
    r.add_argument("scenarios", nargs="*", type=Path)
    d = sub.add_parser("diff")
    d.add_argument("before", type=Path)
    d.add_argument("after", type=Path)
    d.add_argument("--rename", action="append", default=[], metavar="OLD=NEW")
    d.add_argument("--exact", action="store_true", help="floats equal bit for bit (default: to 1e-9 relative)")
    # options and positionals in any order (``record OUT --seeds 3 a.yaml b.yaml``): argparse cannot
    # intermix with subparsers, so the action's own parser reads the rest
    actions = {"record": r, "diff": d}
    if argv and argv[0] in actions:
        args = actions[argv[0]].parse_intermixed_args(argv[1:])
        args.action = argv[0]
    else:
        args = ap.parse_args(argv)  # no or an unknown action, or --help: argparse's message
    if args.action == "record":
        record(args.out, args.seeds, args.duration, args.scenarios or sorted((ROOT / "scenarios").glob("*.yaml")))
        return 0
    return diff(args.before, args.after, dict(r.split("=", 1) for r in args.rename), args.exact)


if __name__ == "__main__":
    sys.exit(main())
