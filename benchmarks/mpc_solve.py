"""MPC solve time on the METANET beltway at 4, 8 and 16 interchanges (p50/p95 over receding steps).

Each case runs the coordinated ramp-metering + route-guidance MPC in closed loop on the pure model
for ``--steps`` control steps (60 s each, 10 s model step, 5-step horizon) around the peak of a
demand that loads the busiest ring link to ``--load`` x capacity (2 lanes, OD favouring long trips,
demand capped at 95 % of the two on-ramps' capacity), starting near critical density with half-full
ramp queues, and prints solve-time percentiles with the growth ratio against the 4-interchange ring.

    python benchmarks/mpc_solve.py [--steps 10] [--load 1.05] [--sizes 4 8 16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC, closed_loop, mpc_policy
from corridor.traffic.metanet import steady_state
from corridor.traffic.metanet_networks import (
    BeltwayLayout,
    beltway,
    beltway_demand_for_load,
    beltway_demands,
)


def run_case(n: int, steps: int, load: float, cfg: MPCConfig) -> dict[str, float]:
    """Closed-loop MPC on an n-interchange beltway; returns sizes, solve-time stats and TTS."""
    layout = BeltwayLayout(n_interchanges=n, lanes=2, trip_exponent=2.0)
    net = beltway(layout)
    mpc = RampMeteringMPC(net, cfg)
    k = steps * mpc.m
    t_h = 0.5 + np.arange(k) * net.params.step_h  # around the peak of the profile (0.75 h)
    ramp_limit_vph = 0.95 * 2 * layout.ramp_cap_vph  # two on-ramps per interchange
    d = beltway_demands(t_h, min(beltway_demand_for_load(layout, load), ramp_limit_vph), n)
    x0 = steady_state(net, 0.9 * layout.rho_crit)
    x0[2 * net.n_seg:] = 0.5 * layout.ramp_storage_veh  # half-full ramps: storage limits matter
    t0 = time.perf_counter()
    res = closed_loop(net, mpc_policy(mpc), x0, d, mpc.m)
    wall = time.perf_counter() - t0
    st = mpc.solve_time_stats()
    n_var = int(mpc.lay.offsets[-1])
    return {"n": n, "segments": net.n_seg, "meters": net.n_metered, "variables": n_var,
            "p50_s": st["p50_s"], "p95_s": st["p95_s"], "max_s": st["max_s"],
            "fallbacks": st["fallbacks"], "iters": float(np.mean(mpc.iter_counts)), "tts": res.tts_veh_h,
            "wall_s": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--load", type=float, default=1.05)
    ap.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 16])
    ap.add_argument("--time-limit", type=float, default=30.0, help="IPOPT cpu/wall limit per solve [s]")
    args = ap.parse_args()
    cfg = MPCConfig(max_cpu_time_s=args.time_limit)
    rows = [run_case(n, args.steps, args.load, cfg) for n in args.sizes]
    base = rows[0]
    print(f"{'interchanges':>12}{'segments':>9}{'meters':>7}{'NLP vars':>9}{'p50 [s]':>9}{'p95 [s]':>9}"
          f"{'max [s]':>9}{'iters':>7}{'fallbk':>7}{'p50 x':>7}{'p95 x':>7}")
    for r in rows:
        print(f"{r['n']:>12}{r['segments']:>9}{r['meters']:>7}{r['variables']:>9}{r['p50_s']:>9.3f}"
              f"{r['p95_s']:>9.3f}{r['max_s']:>9.3f}{r['iters']:>7.1f}{r['fallbacks']:>7.0f}{r['p50_s'] / base['p50_s']:>7.1f}"
              f"{r['p95_s'] / base['p95_s']:>7.1f}")
    print(f"({args.steps} receding steps each, horizon {cfg.horizon_ctrl_steps} x {cfg.control_step_s:.0f} s, "
          f"load {args.load:.2f} x link capacity, limit {args.time_limit:.0f} s per solve)")


if __name__ == "__main__":
    main()
