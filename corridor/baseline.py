"""Regression baselines on collision counts: short runs of every scenario with fixed seeds.

    python -m corridor.baseline record scenarios/merging.yaml     # (re-)record one scenario
    python -m corridor.baseline record --all                      # every file in scenarios/
    python -m corridor.baseline check scenarios/merging.yaml      # what the test does

A baseline stores, per variant and seed, the collision count, key metrics and each STL spec's space
robustness; ``check`` fails when collisions rise or a spec's robustness drops below its recorded
bound.  Recording is always an explicit command, never a side effect of a test.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

from corridor.batch import expand, run_batch
from corridor.results import ResultStore
from corridor.scenario import load

ROOT = Path(__file__).resolve().parent.parent
BASELINES = ROOT / "tests" / "baselines"
SAFETY_COUNTS = ("collisions", "nmac")  # counts that must never rise
DEFAULT_SHORT_S = 60.0  # [s] simulated per baseline run unless the scenario is shorter


def short_overrides(sc: Any, duration_s: float) -> list[str]:
    d = min(sc.duration, duration_s)
    return [f"duration={d}", f"warmup={min(sc.warmup, d / 4)}", "outputs.signals=false"]


def run_short(path: Path, seeds: int, duration_s: float, workers: int = 2) -> list[dict[str, Any]]:
    sc, _ = load(path)
    sc, raw = load(path, short_overrides(sc, duration_s))
    specs = expand(sc, raw, str(path), seeds)
    with tempfile.TemporaryDirectory() as tmp:
        store = ResultStore(tmp)
        run_batch(specs, store, workers=workers, progress=False)
        df = store.compact([s.run_id for s in specs])
    rows: list[dict[str, Any]] = df.to_dict("records")
    return rows


def summarise(rows: list[dict[str, Any]], key_metrics: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for r in rows:
        entry: dict[str, Any] = {"status": r["status"], "collisions": int(r.get("collisions") or 0)}
        for m in key_metrics:
            v = r.get(m)
            if isinstance(v, int | float) and math.isfinite(v):
                entry[m] = round(float(v), 6)
        for k, v in r.items():
            if k.startswith("spec.") and k.endswith(".space") and isinstance(v, float) and math.isfinite(v):
                entry[k] = round(v, 6)
        if r["status"] != "ok":
            entry["error"] = r.get("error", "")
        out[r["run_id"]] = entry
    return out


def baseline_path(path: Path) -> Path:
    return BASELINES / f"{path.stem}.json"


def record(path: Path, seeds: int = 1, duration_s: float = DEFAULT_SHORT_S) -> Path:
    sc, _ = load(path)
    rows = run_short(path, seeds, duration_s)
    data = {"scenario": path.name, "seeds": seeds, "duration_s": min(sc.duration, duration_s),
            "runs": summarise(rows, sc.metrics)}
    BASELINES.mkdir(parents=True, exist_ok=True)
    out = baseline_path(path)
    out.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return out


def check(path: Path) -> list[str]:
    """Re-run the recorded short runs; returns the regressions found (empty: OK)."""
    ref_file = baseline_path(path)
    if not ref_file.exists():
        return [f"{path.name}: no baseline; record one with: python -m corridor.baseline record {path}"]
    ref = json.loads(ref_file.read_text())
    sc, _ = load(path)
    rows = run_short(path, ref["seeds"], ref["duration_s"])
    now = summarise(rows, sc.metrics)
    problems = []
    for run_id, base in ref["runs"].items():
        cur = now.get(run_id)
        if cur is None:
            problems.append(f"{run_id}: missing (variants or seeds changed; re-record the baseline)")
            continue
        if cur["status"] != "ok":
            problems.append(f"{run_id}: {cur['status']}: {cur.get('error', '')}")
            continue
        for count in SAFETY_COUNTS:
            if count in base and cur.get(count, 0) > base[count]:
                problems.append(f"{run_id}: {count} rose from {base[count]:g} to {cur.get(count, 0):g}")
        for k, v in base.items():
            if k.startswith("spec.") and k.endswith(".space") and cur.get(k, -math.inf) < v - 1e-6:
                problems.append(f"{run_id}: {k} dropped from {v} to {cur.get(k)}")
    return problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m corridor.baseline", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=["record", "check"])
    ap.add_argument("scenarios", nargs="*", help="scenario files (default with --all: scenarios/*.yaml)")
    ap.add_argument("--all", action="store_true")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--duration", type=float, default=DEFAULT_SHORT_S, help="simulated seconds per run")
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.scenarios] or (sorted((ROOT / "scenarios").glob("*.yaml")) if args.all else [])
    if not paths:
        ap.error("name scenario files or use --all")
    failed = False
    for p in paths:
        if args.action == "record":
            print(f"recorded {record(p, args.seeds, args.duration)}")
        else:
            problems = check(p)
            failed |= bool(problems)
            print(f"{p.name}: " + ("ok" if not problems else "; ".join(problems)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
