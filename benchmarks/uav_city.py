"""uav_city: CPU per simulated second vs fleet size, and the fidelity-bias check.

Cost curve (``--n 100 500 2000``): one run of ``scenarios/uav_city.yaml`` (potential field) per N,
each in its own process; CPU is ``time.process_time`` of that process (its children included: the
runs are measured from outside with ``resource.getrusage(RUSAGE_CHILDREN)``), never wall time (the
machine is shared). Printed per N: the CPU per simulated second of the run loop (from the backend's
first tick: ``cpu_per_sim_s``), the same including set-up (JSBSim loads, the city draw), the
real-time factor on one core (1 / CPU per simulated second) and the share of flight time in 6-DOF.

    python benchmarks/uav_city.py --n 100 500 2000 --duration 60

Fidelity bias (``--bias``): at N drones (default 200) in a ``--size`` m city (default 3000 m, about
the density of 2,200 drones in 10 km x 10 km, so a short run has encounters), each seed runs twice,
multi-fidelity and all-6-DOF, with the same seed (the same city, missions and link losses: common
random numbers). Per metric the paired differences (multi - all-6-DOF) get a mean with its 95 %
t-interval and a Wilcoxon signed-rank p-value; the fidelity does not bias a metric when the
interval holds 0. Also printed: the CPU ratio.

    python benchmarks/uav_city.py --bias --seeds 10 --duration 60

Shards (``--shards 1 2``): the same run with the 6-DOF aircraft in 1, 2, ... shard processes
(``backends.air.params.shards``), ``--repeat`` times each, interleaved; printed per run: wall time
of the run loop (from the backend's first tick; the machine is shared: the load average is printed
beside it), the speed-up against the one-shard run of the same round, the CPU of all processes per
simulated second, and whether the rows equal the one-shard run's.

    python benchmarks/uav_city.py --shards 1 2 --n 2000 --duration 30 --repeat 2
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CITY = ROOT / "scenarios" / "uav_city.yaml"
BIAS_METRICS = ("los_per_fh", "nmac_per_fh", "sep_nn_median_m", "sep_nn_p05_m", "sep_min_3d_m", "mission_delay_mean_s")


def one_run(sets: list[str], seed: int) -> dict[str, Any]:
    """One run in this (worker) process: its metrics."""
    from corridor.run import simulate
    from corridor.scenario import load

    sc, _ = load(CITY, sets)
    return simulate(sc, seed)[0]


def timed_run(sets: list[str], seed: int, duration_s: float) -> dict[str, Any]:
    """``one_run`` in a child process; adds ``cpu_total_per_sim_s`` (the child's CPU, set-up included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with ProcessPoolExecutor(1) as ex:
        m = ex.submit(one_run, sets, seed).result()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {**m, "cpu_total_per_sim_s": cpu / duration_s}


def cost_curve(ns: list[int], duration_s: float, seed: int, extra: list[str]) -> None:
    print(f"{'N':>6} {'CPU/sim s (loop)':>17} {'CPU/sim s (total)':>18} {'x real time':>12} {'6-DOF share':>12} "
          f"{'promotions':>11} {'LoS/fh':>8}")
    for n in ns:
        sets = [f"backends.air.params.city.n={n}", f"duration={duration_s}", "controllers.avoid.type=city_potential_field",
                *extra]
        m = timed_run(sets, seed, duration_s)
        print(f"{n:>6} {m['cpu_per_sim_s']:>17.3f} {m['cpu_total_per_sim_s']:>18.3f} {1.0 / m['cpu_per_sim_s']:>12.2f} "
              f"{m['six_dof_share']:>12.3f} {m['promotions']:>11} {m['los_per_fh']:>8.2f}", flush=True)


def shard_speedup(n: int, shards: list[int], duration_s: float, seed: int, repeat: int, extra: list[str]) -> None:
    machine = {"wall_s", "rtf", "cpu_per_sim_s", "cpu_total_per_sim_s"}
    print(f"N={n}, {duration_s:.0f} s, potential field; wall of the run loop (rtf: simulated s per wall s)")
    print(f"{'round':>5} {'shards':>6} {'loop wall [s]':>13} {'speed-up':>9} {'CPU/sim s':>10} {'6-DOF share':>12} "
          f"{'rows = 1 shard':>15} {'load avg (1 min)':>17}")
    for r in range(repeat):
        ref: dict[str, Any] | None = None
        for k in shards:
            sets = [f"backends.air.params.city.n={n}", f"duration={duration_s}",
                    "controllers.avoid.type=city_potential_field", f"backends.air.params.shards={k}", *extra]
            m = timed_run(sets, seed, duration_s)
            wall = duration_s / m["rtf"]
            ref = ref or {**m, "wall": wall}
            same = all(_same(m[c], ref[c]) for c in m if c not in machine)
            print(f"{r:>5} {k:>6} {wall:>13.1f} {ref['wall'] / wall:>9.2f} {m['cpu_per_sim_s']:>10.3f} "
                  f"{m['six_dof_share']:>12.3f} {str(same):>15} {os.getloadavg()[0]:>17.2f}", flush=True)


def _same(a: Any, b: Any) -> bool:
    nan = isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)
    return nan or bool(a == b)


def bias(n: int, size_m: float, seeds: int, duration_s: float, workers: int, extra: list[str]) -> None:
    from scipy import stats

    base = [f"backends.air.params.city.n={n}", f"backends.air.params.city.size_m={size_m}", f"duration={duration_s}",
            "backends.air.params.city.vertiports=20", "controllers.avoid.type=city_potential_field", *extra]
    jobs = [(base + [f"backends.air.params.fidelity.mode={mode}"], s) for s in range(seeds) for mode in ("multi", "jsbsim")]
    with ProcessPoolExecutor(workers) as ex:
        rows = list(ex.map(one_run, *zip(*jobs, strict=True)))
    multi, full = rows[0::2], rows[1::2]
    print(f"fidelity bias: N={n}, {size_m:.0f} m city, {duration_s:.0f} s, {seeds} paired seeds "
          "(multi-fidelity minus all-6-DOF; mean, 95 % t-interval, Wilcoxon p)")
    for k in BIAS_METRICS:
        a, b = np.array([r[k] for r in multi], float), np.array([r[k] for r in full], float)
        ok = np.isfinite(a) & np.isfinite(b)
        d = a[ok] - b[ok]
        half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else np.nan
        p = stats.wilcoxon(d).pvalue if len(d) > 1 and np.any(d != 0) else 1.0
        print(f"  {k:22s} multi {a[ok].mean():9.3f}  6-DOF {b[ok].mean():9.3f}  diff {d.mean():+8.3f} "
              f"[{d.mean() - half:+8.3f}, {d.mean() + half:+8.3f}]  p={p:.2f}  "
              f"{'holds 0' if abs(d.mean()) <= half or np.all(d == 0) else 'BIASED'}")
    share = np.mean([r["six_dof_share"] for r in multi])
    cpu = np.mean([r["cpu_per_sim_s"] for r in full]) / np.mean([r["cpu_per_sim_s"] for r in multi])
    print(f"  6-DOF share (multi) {share:.3f}; CPU per simulated second all-6-DOF / multi = {cpu:.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[100, 500, 2000])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bias", action="store_true", help="the paired fidelity-bias check instead of the cost curve")
    ap.add_argument("--bias-n", type=int, default=200)
    ap.add_argument("--size", type=float, default=3000.0, help="[m] city side of the bias check")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--shards", type=int, nargs="+", help="shard counts to compare (wall time) at the first --n")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of the shard comparison")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run (repeatable), e.g. a fidelity boundary")
    a = ap.parse_args(argv)
    if a.shards:
        shard_speedup(a.n[0], a.shards, a.duration, a.seed, a.repeat, a.set)
    elif a.bias:
        bias(a.bias_n, a.size, a.seeds, a.duration, a.workers, a.set)
    else:
        cost_curve(a.n, a.duration, a.seed, a.set)
    return 0


if __name__ == "__main__":
    sys.exit(main())
