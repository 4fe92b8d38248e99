"""Real-time factor of a JSBSim F450 swarm under corridor's cascade autopilot.

Spawns N quadcopters on a circle (radius 40 m, 30 m up), lets them hover, then flies each to the
antipodal point through the centre (altitudes staggered by 1 m), and prints simulated seconds per
wall-clock second (the real-time factor) for both phases.

    python benchmarks/uav_fleet.py --n 20 --sim-s 30
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from corridor.vehicles.air.autopilot import PositionCommand
from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet


def build(n: int, radius_m: float) -> tuple[JSBSimFleet, np.ndarray]:
    """A fleet of ``n`` F450 on a circle; returns it and their start points [m]."""
    fleet = JSBSimFleet((47.3769, 8.5417, 408.0))
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    starts = np.column_stack([radius_m * np.cos(ang), radius_m * np.sin(ang), 30.0 + np.arange(n) % 5])
    for i, p in enumerate(starts):
        fleet.add(f"uav{i}", "F450", p, heading_rad=float(ang[i]))
    return fleet, starts


def timed(fleet: JSBSimFleet, sim_s: float, dt_s: float = 0.1) -> float:
    """Step ``sim_s`` seconds in ticks of ``dt_s``; return the real-time factor."""
    t0 = time.perf_counter()
    for _ in range(round(sim_s / dt_s)):
        fleet.step(dt_s)
    return sim_s / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="number of F450 quadcopters")
    ap.add_argument("--sim-s", type=float, default=30.0, help="simulated seconds per phase")
    args = ap.parse_args()
    t0 = time.perf_counter()
    fleet, starts = build(args.n, 40.0)
    print(f"spawned {args.n} F450 in {time.perf_counter() - t0:.2f} s wall")
    rtf_hover = timed(fleet, args.sim_s)
    for i, p in enumerate(starts):
        fleet.command(f"uav{i}", PositionCommand((-p[0], -p[1], p[2])))
    rtf_fly = timed(fleet, args.sim_s)
    err = np.linalg.norm(fleet.state().position - starts * [-1, -1, 1], axis=1)
    print(f"hover : real-time factor {rtf_hover:6.1f}x ({args.n} F450, 120 Hz)")
    print(f"swap  : real-time factor {rtf_fly:6.1f}x; max distance to goal after {args.sim_s:.0f} s: "
          f"{err.max():.2f} m")


if __name__ == "__main__":
    main()
