"""Solve one TPCAP parking case.

``python -m corridor.controllers.parking.tpcap CASE.csv --out traj.csv [--plot case.png] [--dt S]
[--max-expansions N] [--max-iter N]``

Writes the trajectory (header ``t,x,y,theta,v,a,steer``, rear-axle centre, one row per ≤ ``--dt``
from the start pose to the goal pose; every number written as Python's ``repr``, which reads back to
the same float, so cases at 1e9 m keep their centimetres), prints the planning time (search /
optimisation), the manoeuvre time, the path length and the number of direction changes. The work is
bounded by expansions and IPOPT iterations, so a case gives the same trajectory on any machine load.
Exit 0 on success, 1 with a one-line reason when no trajectory is found, 2 on bad input (checked
before planning: the case, ``--dt``, the budgets, the search area, and that ``--out`` / ``--plot``
can be written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from corridor.controllers.parking.case import CaseError, read_case
from corridor.controllers.parking.planner import (
    MIN_DT_S,
    InputError,
    NoSolution,
    PlanBudget,
    Trajectory,
    plan,
)

HEADER = "t,x,y,theta,v,a,steer"
MAX_DT_S = 0.1  # TPCAP's largest output step [s]


def format_csv(rows: np.ndarray) -> str:
    """The trajectory CSV: the header, then one line per row, every value ``repr``-exact."""
    return "\n".join([HEADER, *(",".join(repr(float(v)) for v in row) for row in rows)]) + "\n"


def write_csv(path: str | Path, traj: Trajectory) -> None:
    Path(path).write_text(format_csv(traj.as_array()))


def summary(traj: Trajectory) -> str:
    return (f"planning {traj.search_time_s + traj.optimise_time_s:.2f} s (search {traj.search_time_s:.2f} s, "
            f"optimisation {traj.optimise_time_s:.2f} s, result: {traj.stage}); manoeuvre {traj.duration_s:.1f} s; "
            f"length {traj.length_m():.2f} m; direction changes {traj.direction_changes()}")


def writable(path: str, option: str) -> str | None:
    """Why ``path`` cannot be written as ``option``'s file (None: it can). Tries to open it without
    truncating; a file this creates is removed again."""
    if not path.strip():
        return f"{option} is empty: give a file name"
    p = Path(path)
    if p.is_dir():
        return f"{option} {path} is a folder: give a file name"
    if not p.parent.is_dir():
        return f"{option} {path}: the folder {p.parent} does not exist"
    existed = p.exists()
    try:
        with open(p, "a"):
            pass
    except OSError as exc:
        return f"{option} {path}: cannot write ({exc.strerror or exc.__class__.__name__})"
    if not existed:
        p.unlink()
    return None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m corridor.controllers.parking.tpcap",
                                 description="Plan a TPCAP parking case.")
    ap.add_argument("case", help="TPCAP case file (one line of comma-separated numbers)")
    ap.add_argument("--out", required=True, help="trajectory CSV to write")
    ap.add_argument("--plot", help="PNG of the case and the trajectory")
    ap.add_argument("--dt", type=float, default=0.1, help=f"time step of the output [s] (default 0.1; "
                    f"{MIN_DT_S:g} to {MAX_DT_S:g})")
    ap.add_argument("--max-expansions", type=int, default=PlanBudget.coarse_expansions,
                    help="search budget: expansions per coarse search (fine searches get twice as many; "
                    f"default {PlanBudget.coarse_expansions})")
    ap.add_argument("--max-iter", type=int, default=PlanBudget.ipopt_iter,
                    help=f"optimisation budget: IPOPT iterations per solve (default {PlanBudget.ipopt_iter})")
    return ap.parse_args(argv)


def validate(args: argparse.Namespace) -> str | None:
    """The first problem with the options (None: none), before the case is read or planned."""
    if not (MIN_DT_S <= args.dt <= MAX_DT_S):
        return f"--dt must be in [{MIN_DT_S:g}, {MAX_DT_S:g}] s (got {args.dt:g})"
    if args.max_expansions < 1 or args.max_iter < 1:
        return "--max-expansions and --max-iter must be >= 1"
    for option, path in (("--out", args.out), ("--plot", args.plot)):
        if path is not None and (why := writable(path, option)):
            return why
    return None


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if why := validate(args):
        print(f"error: {why}", file=sys.stderr)
        return 2
    budget = PlanBudget(coarse_expansions=args.max_expansions, fine_expansions=2 * args.max_expansions,
                        ipopt_iter=args.max_iter, refine_iter=min(PlanBudget.refine_iter, args.max_iter))
    try:
        case = read_case(args.case)
        traj = plan(case.start, case.goal, case.obstacles, dt_s=args.dt, budget=budget)
    except (CaseError, InputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except NoSolution as exc:
        print(f"no trajectory: {exc}")
        if args.plot:
            from corridor.controllers.parking.plot import plot_case
            plot_case(args.plot, case.start, case.goal, case.obstacles, title=f"{Path(args.case).name}: no trajectory")
        return 1
    try:
        write_csv(args.out, traj)
    except OSError as exc:
        print(f"error: --out {args.out}: cannot write ({exc.strerror or exc.__class__.__name__})", file=sys.stderr)
        return 2
    print(f"{Path(args.case).name}: {summary(traj)}")
    if args.plot:
        from corridor.controllers.parking.plot import plot_case
        plot_case(args.plot, case.start, case.goal, case.obstacles, traj.as_array(),
                  title=f"{Path(args.case).name}: {traj.duration_s:.1f} s, {traj.direction_changes()} direction changes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
