"""Parking planner on the TPCAP cases: planning time split into search and optimisation, manoeuvre
time, path length, direction changes, and the independent checker's verdict.

Each case is planned ``--repeats`` times in one process (the first plan of a node count builds the
NLP; later ones reuse it) and the median is printed. The baseline, measured in the same run, is the
search stage alone with its stop-and-steer time parametrisation: the printed ratios are the full
planner's planning time over the search's, and the optimised manoeuvre time over the baseline's.

    python benchmarks/parking_plan.py [--repeats 3] [CASE.csv ...]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from corridor.controllers.parking import profile
from corridor.controllers.parking.case import read_case
from corridor.controllers.parking.check import check
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, Obstacles
from corridor.controllers.parking.planner import (
    COARSE,
    MARGIN_M,
    NoSolution,
    PlanBudget,
    _default_bounds,
    _search,
    plan,
)

GIVEN = sorted((Path(__file__).resolve().parents[1] / "tests" / "data" / "tpcap").glob("Case*.csv"),
               key=lambda p: int(p.stem[4:]))


def baseline(path: Path) -> tuple[float, float]:
    """Search-only planning time [s] and its stop-and-steer manoeuvre time [s]."""
    case = read_case(path)
    origin = np.array(case.start[:2])
    polys = [p - origin for p in case.obstacles]
    s = (0.0, 0.0, case.start[2])
    g = (case.goal[0] - origin[0], case.goal[1] - origin[1], case.goal[2])
    t0 = time.perf_counter()
    segs = _search(s, g, Obstacles(polys), TPCAP_VEHICLE, _default_bounds(np.array(s), np.array(g), polys),
                   PlanBudget(), COARSE.margin_m, MARGIN_M)
    phases = profile.phases(segs, TPCAP_VEHICLE)
    return time.perf_counter() - t0, phases[-1].t0_s + phases[-1].duration_s


def run_case(path: Path, repeats: int) -> dict[str, object]:
    case = read_case(path)
    runs = []
    for _ in range(repeats):
        try:
            runs.append(plan(case.start, case.goal, case.obstacles))
        except NoSolution as exc:
            return {"case": path.stem, "error": str(exc)}
    base = [baseline(path) for _ in range(repeats)]
    tr = runs[-1]
    med = statistics.median
    return {"case": path.stem, "search_s": med(r.search_time_s for r in runs),
            "opt_s": med(r.optimise_time_s for r in runs), "first_s": runs[0].search_time_s + runs[0].optimise_time_s,
            "total_s": med(r.search_time_s + r.optimise_time_s for r in runs), "stage": tr.stage,
            "manoeuvre_s": tr.duration_s, "length_m": tr.length_m(), "dir_changes": tr.direction_changes(),
            "base_s": med(b[0] for b in base), "base_manoeuvre_s": base[0][1],
            "check": "pass" if not check(case, tr.as_array()) else "FAIL"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", type=Path, default=GIVEN)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"{'case':8} {'plan p50':>9} {'search':>7} {'optim.':>7} {'1st plan':>9} {'x search':>9} "
          f"{'manoeuvre':>10} {'x stop&steer':>13} {'length':>7} {'dir.ch.':>7} {'result':>9} check")
    for path in args.cases:
        r = run_case(path, args.repeats)
        if "error" in r:
            print(f"{r['case']:8} no trajectory: {r['error']}")
            continue
        print(f"{r['case']:8} {r['total_s']:8.2f}s {r['search_s']:6.2f}s {r['opt_s']:6.2f}s {r['first_s']:8.2f}s "
              f"{r['total_s'] / r['base_s']:8.1f}x {r['manoeuvre_s']:9.1f}s "
              f"{r['manoeuvre_s'] / r['base_manoeuvre_s']:12.2f}x {r['length_m']:6.1f}m {r['dir_changes']:7d} "
              f"{r['stage']:>9} {r['check']}")
    print(f"(median of {args.repeats} plans per case; 'x search': planning time over the search stage alone; "
          "'x stop&steer': manoeuvre time over the search path's stop-and-steer parametrisation)")


if __name__ == "__main__":
    main()
