"""Solve one TPCAP parking case.

``python -m corridor.controllers.parking.tpcap CASE.csv --out traj.csv [--plot case.png] [--time-limit S]``

Writes the trajectory (header ``t,x,y,theta,v,a,steer``, rear-axle centre, one row per ≤ 0.1 s from
the start pose to the goal pose), prints the planning time (search / optimisation), the manoeuvre
time, the path length and the number of direction changes. Exit 0 on success, 1 with a one-line
reason when no trajectory is found, 2 on bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from corridor.controllers.parking.case import CaseError, read_case
from corridor.controllers.parking.planner import NoSolution, Trajectory, plan


def write_csv(path: str | Path, traj: Trajectory) -> None:
    rows = traj.as_array()
    np.savetxt(path, rows, delimiter=",", header="t,x,y,theta,v,a,steer", comments="", fmt="%.10g")


def summary(traj: Trajectory) -> str:
    return (f"planning {traj.search_time_s + traj.optimise_time_s:.2f} s (search {traj.search_time_s:.2f} s, "
            f"optimisation {traj.optimise_time_s:.2f} s, result: {traj.stage}); manoeuvre {traj.duration_s:.1f} s; "
            f"length {traj.length_m():.2f} m; direction changes {traj.direction_changes()}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m corridor.controllers.parking.tpcap",
                                 description="Plan a TPCAP parking case.")
    ap.add_argument("case", help="TPCAP case file (one line of comma-separated numbers)")
    ap.add_argument("--out", required=True, help="trajectory CSV to write")
    ap.add_argument("--plot", help="PNG of the case and the trajectory")
    ap.add_argument("--time-limit", type=float, default=30.0, help="planning time limit [s] (default 30)")
    ap.add_argument("--dt", type=float, default=0.1, help="time step of the output [s] (default 0.1)")
    args = ap.parse_args(argv)
    if not (args.time_limit > 0 and 0 < args.dt <= 0.1):
        print("error: --time-limit must be > 0 and --dt in (0, 0.1]", file=sys.stderr)
        return 2
    try:
        case = read_case(args.case)
    except CaseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        traj = plan(case.start, case.goal, case.obstacles, time_limit_s=args.time_limit, dt_s=args.dt)
    except NoSolution as exc:
        print(f"no trajectory: {exc}")
        if args.plot:
            from corridor.controllers.parking.plot import plot_case
            plot_case(args.plot, case.start, case.goal, case.obstacles, title=f"{Path(args.case).name}: no trajectory")
        return 1
    write_csv(args.out, traj)
    print(f"{Path(args.case).name}: {summary(traj)}")
    if args.plot:
        from corridor.controllers.parking.plot import plot_case
        plot_case(args.plot, case.start, case.goal, case.obstacles, traj.as_array(),
                  title=f"{Path(args.case).name}: {traj.duration_s:.1f} s, {traj.direction_changes()} direction changes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
