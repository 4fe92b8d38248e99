"""Parking planner on the TPCAP cases: planning time (wall and CPU) split into search and
optimisation, search expansions, manoeuvre time, path length, direction changes, and the independent
checker's verdict.

The cases are the four development cases (`tests/data/tpcap`) and the generated ones that broke the
planner on held-out cases (`tests/controllers/tpcap_cases.py`): Case1 shifted by 1e9 m, a tight
parallel and a tight perpendicular goal, and the cluttered 37-obstacle lot, seeds 0 to 9. The
machine may be shared: CPU time (``time.process_time``) is the figure to compare; wall time is
printed beside it. Each case is planned ``--repeats`` times in one process (the first plan of a node
count builds the NLP; later ones reuse it) and the median is printed. With ``--baseline`` the search
stage alone is timed too, with its stop-and-steer time parametrisation.

    python benchmarks/parking_plan.py [--repeats 1] [--baseline] [--only NAME ...] [CASE.csv ...]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the generated cases live beside the tests

from corridor.controllers.parking import profile  # noqa: E402
from corridor.controllers.parking.case import Case, read_case  # noqa: E402
from corridor.controllers.parking.check import check  # noqa: E402
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, Obstacles  # noqa: E402
from corridor.controllers.parking.planner import (  # noqa: E402
    COARSE,
    MARGIN_M,
    NoSolution,
    PlanBudget,
    _default_bounds,
    _search,
    plan,
)
from tests.controllers import tpcap_cases as tc  # noqa: E402

GIVEN = sorted((ROOT / "tests" / "data" / "tpcap").glob("Case*.csv"), key=lambda p: int(p.stem[4:]))
CLUTTER_SEEDS = range(10)


def cases(paths: list[Path]) -> Iterator[tuple[str, Case]]:
    """(name, case): the given files, else the development cases and the generated ones."""
    if paths:
        yield from ((p.stem, read_case(p)) for p in paths)
        return
    yield from ((p.stem, read_case(p)) for p in GIVEN)
    yield "Case1+1e9", tc.shifted(read_case(GIVEN[0]), 1e9, 1e9)
    yield "parallel.17", tc.tight_parallel(gap_m=0.17, slot_extra_m=1.0)
    yield "perp.17", tc.tight_perpendicular(gap_m=0.17)
    yield "perp.03", tc.tight_perpendicular(gap_m=0.03)
    for seed in CLUTTER_SEEDS:
        yield f"clutter{seed}", tc.cluttered(n=37, seed=seed, size_m=26.0)


def baseline(case: Case) -> tuple[float, float]:
    """Search-only planning CPU time [s] and its stop-and-steer manoeuvre time [s]."""
    origin = np.array(case.start[:2])
    polys = [np.asarray(p) - origin for p in case.obstacles]
    s = (0.0, 0.0, case.start[2])
    g = (case.goal[0] - origin[0], case.goal[1] - origin[1], case.goal[2])
    c0 = time.process_time()
    segs, _ = _search(s, g, Obstacles(polys), TPCAP_VEHICLE, _default_bounds(np.array(s), np.array(g), polys),
                      PlanBudget(), COARSE.margin_m, MARGIN_M)
    phases = profile.phases(segs, TPCAP_VEHICLE)
    return time.process_time() - c0, phases[-1].t0_s + phases[-1].duration_s


def run_case(name: str, case: Case, repeats: int, with_baseline: bool) -> dict[str, object]:
    runs, cpu, wall = [], [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            runs.append(plan(case.start, case.goal, case.obstacles))
        except NoSolution as exc:
            return {"case": name, "error": str(exc)}
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    tr = runs[-1]
    med = statistics.median
    out = {"case": name, "cpu_s": med(cpu), "wall_s": med(wall), "search_s": med(r.search_time_s for r in runs),
           "opt_s": med(r.optimise_time_s for r in runs), "expansions": tr.expansions, "stage": tr.stage,
           "manoeuvre_s": tr.duration_s, "length_m": tr.length_m(), "dir_changes": tr.direction_changes(),
           "check": "pass" if not check(case, tr.as_array()) else "FAIL"}
    if with_baseline:
        base = [baseline(case) for _ in range(repeats)]
        out["x_search"] = out["cpu_s"] / med(b[0] for b in base)
        out["x_stop_steer"] = tr.duration_s / base[0][1]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", type=Path)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--baseline", action="store_true", help="also time the search stage alone")
    ap.add_argument("--only", nargs="*", default=None, help="only the generated/given cases of these names")
    args = ap.parse_args()
    print(f"{'case':12} {'CPU':>7} {'wall':>7} {'search':>7} {'optim.':>7} {'expans.':>7} {'manoeuvre':>10} "
          f"{'length':>7} {'dir.ch.':>7} {'result':>9} check" + ("   x search  x stop&steer" if args.baseline else ""))
    for name, case in cases(args.cases):
        if args.only is not None and name not in args.only:
            continue
        r = run_case(name, case, args.repeats, args.baseline)
        if "error" in r:
            print(f"{name:12} no trajectory: {r['error']}", flush=True)
            continue
        extra = f" {r['x_search']:9.1f}x {r['x_stop_steer']:12.2f}x" if args.baseline else ""
        print(f"{name:12} {r['cpu_s']:6.2f}s {r['wall_s']:6.2f}s {r['search_s']:6.2f}s {r['opt_s']:6.2f}s "
              f"{r['expansions']:7d} {r['manoeuvre_s']:9.3f}s {r['length_m']:6.1f}m {r['dir_changes']:7d} "
              f"{r['stage']:>9} {r['check']}{extra}", flush=True)
    print(f"(median of {args.repeats} plan(s) per case; CPU: time.process_time of the whole plan; wall: "
          "time.perf_counter; search / optim.: wall time of each stage; expans.: search expansions)")


if __name__ == "__main__":
    main()
