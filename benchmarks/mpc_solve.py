"""MPC solve time on the METANET beltway at 4, 8 and 16 interchanges (p50/p95 over receding steps).

Each case runs the coordinated ramp-metering + route-guidance MPC in closed loop on the pure model
for ``--steps`` control steps (60 s each, 10 s model step, 5-step horizon) around the peak of a
demand that loads the busiest ring link to ``--load`` x capacity (2 lanes, OD favouring long trips,
demand capped at 95 % of the two on-ramps' capacity), starting near critical density with half-full
ramp queues, and prints solve-time percentiles with the growth ratio against the 4-interchange ring.

Each case runs once per configuration, back to back in the same run so all see the same machine
load: corridor's MPC configuration; ``2thr``, the same with CasADi's OpenBLAS on two threads
(its default of one per core on the 2-core machine where corridor ran before ``MPCConfig.blas_threads``);
``previous``, the configuration before issue 16 (MUMPS choosing its own ordering, two BLAS
threads); and, when asked for, ``+duals``, the opt-in dual
warm start on top of corridor's (``MPCConfig.warm_start_duals``).  ``cpu/iter`` is the CPU time of
all solves over all their IPOPT iterations; ``benchmarks/mpc_kkt_structure.py`` explains its growth.

    python benchmarks/mpc_solve.py [--steps 10] [--load 1.05] [--sizes 4 8 16] [--quick]
                                   [--configs corridor 2thr previous +duals]
"""

from __future__ import annotations

import argparse
import itertools
import time
from typing import Any

import numpy as np

from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC, closed_loop, mpc_policy
from corridor.traffic.macro.metanet import steady_state
from corridor.traffic.macro.metanet_networks import (
    BeltwayLayout,
    beltway,
    beltway_demand_for_load,
    beltway_demands,
)


def run_case(n: int, steps: int, load: float, cfg: MPCConfig) -> dict[str, Any]:
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
            "cpu_p50_s": float(np.percentile(mpc.solve_cpu_s, 50)),
            "cpu_p95_s": float(np.percentile(mpc.solve_cpu_s, 95)), "order": mpc.pivot_order,
            "cpu_per_iter_s": float(np.sum(mpc.solve_cpu_s)) / max(1, int(np.sum(mpc.iter_counts))),
            "fallbacks": st["fallbacks"], "iters": float(np.mean(mpc.iter_counts)), "tts": res.tts_veh_h,
            "wall_s": wall}


PREVIOUS: dict[str, Any] = {"mumps_pivot_order": 7, "warm_start_duals": False}  # before issue 16: MUMPS chose
# its own ordering, and warm solves started from the shifted primal solution only


def _growth(rows: list[dict[str, Any]], key: str) -> str:
    """Ratio of ``key`` between successive sizes (per doubling when the sizes double)."""
    return " ".join(f"x{b[key] / a[key]:.2f}" for a, b in zip(rows, rows[1:]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--load", type=float, default=1.05)
    ap.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 16])
    ap.add_argument("--time-limit", type=float, default=30.0, help="IPOPT cpu/wall limit per solve [s]")
    ap.add_argument("--quick", action="store_true", help="4 receding steps per case (for make bench)")
    ap.add_argument("--configs", nargs="+", default=["corridor", "2thr", "previous"],
                    choices=["corridor", "2thr", "previous", "+duals"])
    args = ap.parse_args()
    steps = 4 if args.quick else args.steps
    every = {"corridor": MPCConfig(max_cpu_time_s=args.time_limit),
             "2thr": MPCConfig(max_cpu_time_s=args.time_limit, blas_threads=2),
             "previous": MPCConfig(max_cpu_time_s=args.time_limit, blas_threads=2, **PREVIOUS),
             "+duals": MPCConfig(max_cpu_time_s=args.time_limit, warm_start_duals=True)}
    configs = {name: every[name] for name in dict.fromkeys(["corridor", *args.configs])}
    results: dict[str, list[dict[str, Any]]] = {name: [] for name in configs}
    for n in args.sizes:  # both configurations of one size back to back: the same machine load
        for name, cfg in configs.items():
            results[name].append(run_case(n, steps, args.load, cfg))
    print(f"{'config':>9}{'interch.':>9}{'NLP vars':>9}{'order':>6}{'p50 [s]':>9}{'p95 [s]':>9}{'max [s]':>9}"
          f"{'cpu p50':>9}{'cpu p95':>9}{'iters':>7}{'cpu/iter':>9}{'fallbk':>7}{'TTS [veh h]':>13}")
    for n_i in range(len(args.sizes)):
        for name, rows in results.items():
            r = rows[n_i]
            print(f"{name:>9}{r['n']:>9}{r['variables']:>9}{r['order']:>6}{r['p50_s']:>9.3f}{r['p95_s']:>9.3f}"
                  f"{r['max_s']:>9.3f}{r['cpu_p50_s']:>9.3f}{r['cpu_p95_s']:>9.3f}{r['iters']:>7.1f}"
                  f"{r['cpu_per_iter_s']:>9.4f}{r['fallbacks']:>7.0f}{r['tts']:>13.4f}")
    sizes = " -> ".join(str(n) for n in args.sizes)
    for name, rows in results.items():
        print(f"{name:>9}: growth {sizes}: wall p50 {_growth(rows, 'p50_s')}, p95 {_growth(rows, 'p95_s')}; "
              f"cpu p50 {_growth(rows, 'cpu_p50_s')}, p95 {_growth(rows, 'cpu_p95_s')}, "
              f"per iteration {_growth(rows, 'cpu_per_iter_s')}")
    pairs = [("corridor", a) for a in configs if a != "corridor"]
    for (a, b), n_i in itertools.product(pairs, range(len(args.sizes))):
        c, p, n = results[a][n_i], results[b][n_i], args.sizes[n_i]
        print(f"{n:>3} interchanges: {a} / {b}: wall p50 {c['p50_s'] / p['p50_s']:.2f}, "
              f"p95 {c['p95_s'] / p['p95_s']:.2f}; cpu p50 {c['cpu_p50_s'] / p['cpu_p50_s']:.2f}, "
              f"p95 {c['cpu_p95_s'] / p['cpu_p95_s']:.2f}, per iteration {c['cpu_per_iter_s'] / p['cpu_per_iter_s']:.2f}; "
              f"TTS difference {c['tts'] - p['tts']:+.4f} veh h")
    print(f"({steps} receding steps each, horizon {configs['corridor'].horizon_ctrl_steps} x "
          f"{configs['corridor'].control_step_s:.0f} s, load {args.load:.2f} x link capacity, limit "
          f"{args.time_limit:.0f} s per solve; previous = IPOPT/MUMPS with {PREVIOUS}; wall times on this "
          f"machine under its present load: compare ratios)")


if __name__ == "__main__":
    main()
