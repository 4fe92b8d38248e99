"""uav_city: CPU per simulated second vs fleet size, and the fidelity-bias check.

Cost curve (``--n 100 500 2000``): one run of ``scenarios/uav_city.yaml`` (potential field) per N,
each in its own process; CPU is ``time.process_time`` of that process (its children included: the
runs are measured from outside with ``resource.getrusage(RUSAGE_CHILDREN)``), never wall time (the
machine is shared). Printed per N: the CPU per simulated second of the run loop (from the backend's
first tick: ``cpu_per_sim_s``), the same including set-up (JSBSim loads, the city draw), the
real-time factor on one core (1 / CPU per simulated second), the share of flight time in 6-DOF, and
the CPU per simulated second spent growing the FDM pools (model loads, spin-ups: the first seconds)
and on the promotions' in-flight spawns.

    python benchmarks/uav_city.py --n 100 500 2000 --duration 60

Fidelity bias (``--bias``): at N drones (default 200) in a ``--size`` m city (default 3000 m, about
the density of 2,200 drones in 10 km x 10 km, so a short run has encounters), each seed runs twice,
all-6-DOF and once per multi-fidelity ``--variant`` (default: the scenario's boundaries), with the
same seed (the same city, missions and link losses: common random numbers). Per metric the paired
differences (multi - all-6-DOF) get a mean with its 95 % t-interval, a 95 % bootstrap interval
(seeds resampled) and a Wilcoxon signed-rank p-value; the fidelity does not bias a metric when both
intervals hold 0. The nearest-approach distributions (each aircraft's smallest distance to another,
pooled over the seeds) get quantile differences with intervals from resampling the paired seeds,
and a two-sample KS statistic with a paired permutation p-value. Also printed: the CPU ratio.

    python benchmarks/uav_city.py --bias --seeds 50 --duration 30 \
        --variant default: --variant converging:backends.air.params.fidelity.promote_on=converging

Shards (``--shards 1 2``): the same run split over 1, 2, ... processes (``backends.air.params.shards``,
``corridor.shards``), ``--repeat`` times each, interleaved; printed per run: wall time of the run
loop (from the backend's first tick; the machine is shared: the load average is printed beside it),
the speed-up against the one-shard run of the same round, the CPU per simulated second of all
ranks and of each, the speed-up the CPU split allows and the replicated (serial) share (both from
CPU times: fair under load), and whether the rows equal the one-shard run's.

    python benchmarks/uav_city.py --shards 1 2 --n 2000 --duration 30 --repeat 2

With ``--profile`` (``--profile-out FILE`` also appends the profiles to FILE as pickles) every run
is profiled (``corridor.tick_profile``: thread CPU per tick and part on every rank, the rows do not
change) and each sharded run prints, per part, the CPU per tick of the one-shard run and of each
rank, the ranks' sum over the one-shard value (1: divided, K: replicated), how uneven the ranks are
tick by tick, the exchange (of which the pickling) and the idle work apart, and the predicted wall
speed-up on one free core per rank (the one-shard loop's CPU over the sum, per segment between two
collectives, of the slowest rank's CPU plus a round trip: ``predict_wall``). CPU times, so it holds
under load; the machine's load still inflates CPU times by 10-30 % from run to run.

    python benchmarks/uav_city.py --shards 1 2 --n 2000 --duration 20 --profile
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import resource
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from functools import partial
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


def one_run_switch_cost(sets: list[str], seed: int) -> dict[str, Any]:
    """``one_run`` plus the CPU per simulated second spent growing the FDM pools (``pool_cpu_per_sim_s``:
    model loads and spin-ups, a cost of a run's first seconds) and on the promotions' in-flight spawns
    (``spawn_cpu_per_sim_s``); one-process runs only (NaN with shards)."""
    from corridor.run import simulate
    from corridor.scenario import load

    sc, _ = load(CITY, sets)
    m, ctx, _ = simulate(sc, seed)
    js = ctx.components["air"].js
    return {**m, "pool_cpu_per_sim_s": getattr(js, "warm_cpu_s", math.nan) / sc.duration,
            "spawn_cpu_per_sim_s": getattr(js, "spawn_cpu_s", math.nan) / sc.duration}


def one_run_exchange(sets: list[str], seed: int, profile: bool = False) -> dict[str, Any]:
    """``one_run`` plus, for a sharded run, where its CPU went: ``rank_cpu_per_sim_s`` (each rank's
    process from the first tick: rank 0 is the run's own process), and per tick the collectives
    (``rounds_per_tick``) and rank 0's wall time inside them (``wait_ms_per_tick``: the exchange plus
    waiting for the slower rank). ``profile``: every rank's ``TickProfile.summary()`` (``profiles``)."""
    from corridor.run import simulate
    from corridor.scenario import load

    sc, _ = load(CITY, sets)
    m, ctx, _ = simulate(sc, seed, profile=profile)
    air, sim_s = ctx.components["air"], sc.duration
    comm = ctx.shard
    if profile:
        m = {**m, "profiles": ctx.profiles}
    if comm is None:
        return {**m, "rank_cpu_per_sim_s": [m["cpu_per_sim_s"]]}
    ticks = round(sim_s / sc.dt)
    return {**m, "rank_cpu_per_sim_s": [c / sim_s for c in air.rank_cpu_s], "rounds_per_tick": comm.rounds / ticks,
            "wait_ms_per_tick": 1e3 * comm.wait_s / ticks}


def timed_run(sets: list[str], seed: int, duration_s: float, fn: Any = one_run) -> dict[str, Any]:
    """``fn`` (``one_run``) in a child process; adds ``cpu_total_per_sim_s`` (the child's CPU, set-up included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with ProcessPoolExecutor(1) as ex:
        m = ex.submit(fn, sets, seed).result()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {**m, "cpu_total_per_sim_s": cpu / duration_s}


def cost_curve(ns: list[int], duration_s: float, seed: int, extra: list[str]) -> None:
    print(f"{'N':>6} {'CPU/sim s (loop)':>17} {'CPU/sim s (total)':>18} {'x real time':>12} {'6-DOF share':>12} "
          f"{'promotions':>11} {'LoS/fh':>8} {'pool growth':>12} {'spawns':>7}")
    for n in ns:
        sets = [f"backends.air.params.city.n={n}", f"duration={duration_s}", "controllers.avoid.type=city_potential_field",
                *extra]
        m = timed_run(sets, seed, duration_s, one_run_switch_cost)
        print(f"{n:>6} {m['cpu_per_sim_s']:>17.3f} {m['cpu_total_per_sim_s']:>18.3f} {1.0 / m['cpu_per_sim_s']:>12.2f} "
              f"{m['six_dof_share']:>12.3f} {m['promotions']:>11} {m['los_per_fh']:>8.2f} "
              f"{m['pool_cpu_per_sim_s']:>12.3f} {m['spawn_cpu_per_sim_s']:>7.3f}", flush=True)


def shard_speedup(n: int, shards: list[int], duration_s: float, seed: int, repeat: int, extra: list[str],
                  profile: bool = False, profile_out: Path | None = None) -> None:
    """Per run: the wall of the run loop and its speed-up against the round's one-shard run (fair on
    an idle machine only), the CPU per simulated s of all ranks and of each, the speed-up the CPU
    allows (one-shard CPU / the busiest rank's CPU: the wall speed-up with a free core per rank and
    no waiting), the replicated share (what every rank computes: (sum of the ranks' CPU - one-shard
    CPU) / (K - 1), over the one-shard CPU; Amdahl's serial part), whether the rows equal the
    one-shard run's, the load, and the collectives per tick."""
    machine = {"wall_s", "rtf", "cpu_per_sim_s", "cpu_total_per_sim_s", "rank_cpu_per_sim_s", "rounds_per_tick",
               "wait_ms_per_tick", "profiles"}
    fn = partial(one_run_exchange, profile=profile)
    print(f"N={n}, {duration_s:.0f} s, potential field; wall of the run loop (rtf: simulated s per wall s)")
    print(f"{'round':>5} {'shards':>6} {'loop wall [s]':>13} {'speed-up':>9} {'CPU/sim s':>10} {'per rank':>16} "
          f"{'CPU bound':>10} {'replicated':>11} {'6-DOF share':>12} {'rows = 1 shard':>15} {'load (1 min)':>13}  exchange")
    for r in range(repeat):
        ref: dict[str, Any] | None = None
        for k in shards:
            sets = [f"backends.air.params.city.n={n}", f"duration={duration_s}",
                    "controllers.avoid.type=city_potential_field", f"backends.air.params.shards={k}", *extra]
            m = timed_run(sets, seed, duration_s, fn)
            wall = duration_s / m["rtf"]
            ref = ref or {**m, "wall": wall}
            same = all(_same(m[c], ref[c]) for c in m if c not in machine)
            ranks = m["rank_cpu_per_sim_s"]
            bound = ref["cpu_per_sim_s"] / max(ranks)
            repl = (sum(ranks) - ref["cpu_per_sim_s"]) / (k - 1) / ref["cpu_per_sim_s"] if k > 1 else float("nan")
            ex = (f"{m['rounds_per_tick']:.2f} collectives/tick, rank 0 waits {m['wait_ms_per_tick']:.2f} ms/tick"
                  if "rounds_per_tick" in m else "")
            print(f"{r:>5} {k:>6} {wall:>13.1f} {ref['wall'] / wall:>9.2f} {m['cpu_per_sim_s']:>10.3f} "
                  f"{' / '.join(f'{c:.3f}' for c in ranks):>16} {bound:>10.2f} {repl:>11.2f} {m['six_dof_share']:>12.3f} "
                  f"{str(same):>15} {os.getloadavg()[0]:>13.2f}  {ex}", flush=True)
            if profile and k > 1:
                print_profile(ref["profiles"][0], m["profiles"])
            if profile_out is not None:
                with profile_out.open("ab") as f:
                    pickle.dump({"round": r, "shards": k, "profiles": m["profiles"]}, f)


def print_profile(one: dict[str, Any], ranks: list[dict[str, Any]]) -> None:
    """Per part, the CPU per tick [ms] of the one-shard run and of each rank (thread CPU, the
    collectives' CPU apart as ``exchange``, of which ``serialise``), the ranks' sum over the one-shard
    value (1: replicated work, 1/K... : divided), the wall inside the collectives, and the predicted
    wall speed-up on one free core per rank (``corridor.tick_profile.predict_wall``)."""
    from corridor.tick_profile import predict_wall

    ticks = one["ticks"]
    names = sorted(set(one["parts"]) | {k for r in ranks for k in r["parts"]},
                   key=lambda k: -one["parts"].get(k, np.zeros(1)).sum())
    print(f"    {'part':24s} {'1 shard':>8} " + " ".join(f"{'rank ' + str(r):>8}" for r in range(len(ranks)))
          + f" {'sum/1':>6} {'uneven':>7}  [CPU ms per tick; uneven: mean over ticks of max - mean over ranks]")
    for name in names:
        a = one["parts"].get(name, np.zeros(ticks)).sum() / ticks * 1e3
        series = np.array([r["parts"].get(name, np.zeros(ticks)) for r in ranks])  # (ranks, ticks)
        per = series.sum(axis=1) / ticks * 1e3
        uneven = float((series.max(axis=0) - series.mean(axis=0)).mean() * 1e3)
        print(f"    {name:24s} {a:8.3f} " + " ".join(f"{c:8.3f}" for c in per)
              + f" {per.sum() / a if a > 0 else math.nan:6.2f} {uneven:7.3f}")
    loop = [r["loop_cpu_s"] / ticks * 1e3 for r in ranks]
    print(f"    {'tick loop (thread CPU)':24s} {one['loop_cpu_s'] / ticks * 1e3:8.3f} " + " ".join(f"{c:8.3f}" for c in loop))
    print(f"    {'wall in collectives':24s} {'':8s} " + " ".join(f"{r['wait_s'] / ticks * 1e3:8.3f}" for r in ranks)
          + f"   ({len(ranks[0]['trace']) / ticks:.2f} collectives per tick, round trip "
          f"{ranks[0]['rtt_s'] * 1e6:.0f} us)")
    wall, tick_max = predict_wall(ranks)
    print(f"    predicted wall speed-up (free core per rank): {one['loop_cpu_s'] / wall:.2f} "
          f"(per segment between collectives; per tick only: {one['loop_cpu_s'] / tick_max:.2f}; "
          f"CPU split: {one['loop_cpu_s'] / max(r['loop_cpu_s'] for r in ranks):.2f})", flush=True)


def _same(a: Any, b: Any) -> bool:
    nan = isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)
    return nan or bool(a == b)


def one_run_nn(sets: list[str], seed: int) -> dict[str, Any]:
    """``one_run`` plus every aircraft's nearest approach over the run [m] (``nn``, the separation
    monitor's per-aircraft minimum: the distribution the fidelity check compares)."""
    from corridor.run import simulate
    from corridor.scenario import load

    sc, _ = load(CITY, sets)
    m, ctx, _ = simulate(sc, seed)
    nn = ctx.components["separation"].nn
    return {**m, "nn": np.asarray(nn if nn is not None else [], float)}


def _paired(d: np.ndarray, rng: np.random.Generator, boot: int = 10_000) -> tuple[float, float, float, float]:
    """Mean of the paired differences ``d``, its 95 % t-interval half-width, its 95 % bootstrap
    (percentile, resampling seeds) interval."""
    from scipy import stats

    if len(d) < 2:
        return float(d.mean()) if len(d) else math.nan, math.nan, math.nan, math.nan
    half = float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    means = d[rng.integers(0, len(d), (boot, len(d)))].mean(axis=1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return float(d.mean()), half, float(lo), float(hi)


NN_QUANTILES = (0.01, 0.05, 0.25, 0.5)


def _nn_tests(a: list[np.ndarray], b: list[np.ndarray], rng: np.random.Generator, boot: int = 2000
              ) -> tuple[list[tuple[float, float, float, float]], float, float]:
    """Nearest-approach distributions, pooled over seeds (multi ``a`` vs all-6-DOF ``b``, per seed):
    per quantile (q, difference, 95 % interval by resampling the paired seeds); the two-sample KS
    statistic D of the pools and its p-value by a paired permutation test (the two runs of a seed
    swap labels at random, which under no fidelity effect leaves the pools' law unchanged)."""
    from scipy import stats

    def qdiff(ix: np.ndarray) -> np.ndarray:
        pa, pb = np.concatenate([a[i] for i in ix]), np.concatenate([b[i] for i in ix])
        return np.quantile(pa, NN_QUANTILES) - np.quantile(pb, NN_QUANTILES)

    k = len(a)
    est = qdiff(np.arange(k))
    reps = np.array([qdiff(rng.integers(0, k, k)) for _ in range(boot)])
    lo, hi = np.quantile(reps, 0.025, axis=0), np.quantile(reps, 0.975, axis=0)
    rows = [(q, float(e), float(x), float(y)) for q, e, x, y in zip(NN_QUANTILES, est, lo, hi, strict=True)]
    d0 = stats.ks_2samp(np.concatenate(a), np.concatenate(b)).statistic
    perm = []
    for _ in range(boot // 4):
        swap = rng.random(k) < 0.5
        pa = np.concatenate([b[i] if swap[i] else a[i] for i in range(k)])
        pb = np.concatenate([a[i] if swap[i] else b[i] for i in range(k)])
        perm.append(stats.ks_2samp(pa, pb).statistic)
    p = (1 + int(np.sum(np.array(perm) >= d0))) / (1 + len(perm))
    return rows, float(d0), p


def _load_cache(path: Path | None, cfg: str) -> dict[tuple[str, int], dict[str, Any]]:
    """Finished runs of an earlier (or interrupted) bias check with the same city and run settings
    ``cfg``: (variant, seed) -> row. Rows of other settings are skipped; rows without ``cfg`` (caches
    written before it was recorded) are taken as they are."""
    out: dict[tuple[str, int], dict[str, Any]] = {}
    if path is not None and path.exists():
        for line in path.read_text().splitlines():
            r = json.loads(line)
            if r.get("cfg", cfg) == cfg:
                out[(r["variant"], r["seed"])] = {**r, "nn": np.asarray(r["nn"], float)}
    return out


def bias(n: int, size_m: float, seeds: int, duration_s: float, workers: int, extra: list[str],
         variants: dict[str, list[str]], cache: Path | None = None, analyse_only: bool = False,
         first_seed: int = 0, reference_only: bool = False) -> None:
    """The paired fidelity check: every seed runs all-6-DOF once and each multi-fidelity variant
    (its ``--set`` list) once, with the same seed (common random numbers). With ``cache`` every
    finished run is appended there (JSON lines) and reused: an interrupted check resumes, and
    ``analyse_only`` analyses the seeds whose runs are all there. The all-6-DOF runs do not depend on
    the boundaries, so a cache's ``jsbsim`` rows serve every later variant of the same city and run
    settings (``reference_only`` runs just those, and reports nothing). Seeds ``first_seed`` ...
    ``first_seed + seeds - 1`` (choose boundaries on other seeds than the final check's)."""
    base = [f"backends.air.params.city.n={n}", f"backends.air.params.city.size_m={size_m}", f"duration={duration_s}",
            "backends.air.params.city.vertiports=20", "controllers.avoid.type=city_potential_field", *extra]
    modes = {"jsbsim": ["backends.air.params.fidelity.mode=jsbsim"],
             **{name: ["backends.air.params.fidelity.mode=multi", *sets] for name, sets in variants.items()}}
    cfg = " ".join(base)
    done = _load_cache(cache, cfg)
    seed_range = range(first_seed, first_seed + seeds)
    if reference_only:
        modes = {"jsbsim": modes["jsbsim"]}
    todo = [(name, s) for s in seed_range for name in modes if (name, s) not in done]
    if todo and not analyse_only:
        with ProcessPoolExecutor(workers) as ex:
            futures = {ex.submit(one_run_nn, base + modes[name], s): (name, s) for name, s in todo}
            for fut in as_completed(futures):
                name, s = futures[fut]
                r = {k: v for k, v in fut.result().items() if k in (*BIAS_METRICS, "six_dof_share", "cpu_per_sim_s",
                                                                      "nn")}
                done[(name, s)] = r
                if cache is not None:
                    with cache.open("a") as f:
                        f.write(json.dumps({**r, "variant": name, "seed": s, "cfg": cfg, "nn": r["nn"].tolist()}) + "\n")
    if reference_only:
        print(f"all-6-DOF rows of seeds {first_seed}-{first_seed + seeds - 1} in {cache}")
        return
    complete = [s for s in seed_range if all((name, s) in done for name in modes)]
    full = [done[("jsbsim", s)] for s in complete]
    for name in variants:
        _bias_report(name, variants[name], [done[(name, s)] for s in complete], full, n, size_m, duration_s)
    names = list(variants)
    for name in names[1:]:  # what the boundary changes, the all-6-DOF runs aside
        _contrast(name, names[0], [done[(name, s)] for s in complete], [done[(names[0], s)] for s in complete])


def _contrast(name: str, ref: str, a: list[dict[str, Any]], b: list[dict[str, Any]]) -> None:
    """Paired differences between two multi-fidelity variants (mean, 95 % t-interval)."""
    from scipy import stats

    print(f"contrast {name} minus {ref} ({len(a)} paired seeds; mean, 95 % t-interval)")
    for k in BIAS_METRICS:
        x, y = np.array([r[k] for r in a], float), np.array([r[k] for r in b], float)
        ok = np.isfinite(x) & np.isfinite(y)
        d = x[ok] - y[ok]
        if len(d) < 2:
            continue
        half = float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
        print(f"  {k:22s} {d.mean():+8.3f} [{d.mean() - half:+8.3f}, {d.mean() + half:+8.3f}]")


def _bias_report(name: str, sets: list[str], multi: list[dict[str, Any]], full: list[dict[str, Any]], n: int,
                 size_m: float, duration_s: float) -> None:
    from scipy import stats

    rng = np.random.default_rng(0)
    print(f"fidelity bias [{name}: {' '.join(sets) or 'scenario boundaries'}]: N={n}, {size_m:.0f} m city, "
          f"{duration_s:.0f} s, {len(multi)} paired seeds (multi-fidelity minus all-6-DOF; mean, 95 % t-interval, "
          "95 % bootstrap interval over seeds, Wilcoxon signed-rank p)")
    if len(multi) < 2:
        print("  fewer than 2 complete seeds")
        return
    for k in BIAS_METRICS:
        a, b = np.array([r[k] for r in multi], float), np.array([r[k] for r in full], float)
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 2:
            print(f"  {k:22s} fewer than 2 seeds with a value")
            continue
        d = a[ok] - b[ok]
        mean, half, blo, bhi = _paired(d, rng)
        p = stats.wilcoxon(d).pvalue if len(d) > 1 and np.any(d != 0) else 1.0
        holds = (abs(mean) <= half and blo <= 0.0 <= bhi) or bool(np.all(d == 0))
        print(f"  {k:22s} multi {a[ok].mean():9.3f}  6-DOF {b[ok].mean():9.3f}  diff {mean:+8.3f} "
              f"t [{mean - half:+8.3f}, {mean + half:+8.3f}]  boot [{blo:+8.3f}, {bhi:+8.3f}]  p={p:.2f}  "
              f"{'holds 0' if holds else 'BIASED'}")
    qrows, ks_d, ks_p = _nn_tests([r["nn"] for r in multi], [r["nn"] for r in full], rng)
    print("  nearest approach per aircraft, pooled over seeds: quantile difference [m] (95 % interval, "
          "seeds resampled in pairs)")
    for q, e, lo, hi in qrows:
        print(f"    q{q:<5} {e:+7.3f} [{lo:+7.3f}, {hi:+7.3f}]  {'holds 0' if lo <= 0.0 <= hi else 'BIASED'}")
    print(f"    two-sample KS D = {ks_d:.4f}, paired permutation p = {ks_p:.3f}")
    cpu_m, cpu_f = (np.mean([r["cpu_per_sim_s"] for r in rows]) for rows in (multi, full))
    print(f"  6-DOF share (multi) {np.mean([r['six_dof_share'] for r in multi]):.3f}; CPU per simulated second "
          f"all-6-DOF / multi = {cpu_f / cpu_m:.2f} (all-6-DOF {cpu_f:.3f} s, multi {cpu_m:.3f} s)", flush=True)


def _variants(specs: list[str]) -> dict[str, list[str]]:
    """``--variant name:key=value,key=value`` -> {name: [key=value, ...]} (default: the scenario's)."""
    out: dict[str, list[str]] = {}
    for spec in specs or ["multi:"]:
        name, _, sets = spec.partition(":")
        out[name] = [s for s in sets.split(",") if s]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[100, 500, 2000])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bias", action="store_true", help="the paired fidelity-bias check instead of the cost curve")
    ap.add_argument("--bias-n", type=int, default=200)
    ap.add_argument("--size", type=float, default=3000.0, help="[m] city side of the bias check")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0, help="bias check: seeds --first-seed ... + --seeds - 1")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--shards", type=int, nargs="+", help="shard counts to compare (wall time) at the first --n")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of the shard comparison")
    ap.add_argument("--profile", action="store_true",
                    help="shard comparison: CPU per tick and part of every rank, and the predicted wall speed-up")
    ap.add_argument("--profile-out", type=Path, help="with --profile: append every run's profiles here (pickles)")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                    help="a multi-fidelity variant of the bias check (repeatable; they share the all-6-DOF runs)")
    ap.add_argument("--cache", type=Path, help="bias check: append every finished run here (JSON lines) and reuse it")
    ap.add_argument("--analyse-only", action="store_true", help="bias check: analyse the cached runs, run nothing")
    ap.add_argument("--reference-only", action="store_true",
                    help="bias check: run only the all-6-DOF rows into --cache (they serve every boundary)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run (repeatable), e.g. a fidelity boundary")
    a = ap.parse_args(argv)
    if a.reference_only and a.cache is None:
        ap.error("--reference-only needs --cache (the file that keeps the all-6-DOF rows)")
    if a.shards:
        shard_speedup(a.n[0], a.shards, a.duration, a.seed, a.repeat, a.set, a.profile or a.profile_out is not None,
                      a.profile_out)
    elif a.bias:
        bias(a.bias_n, a.size, a.seeds, a.duration, a.workers, a.set, _variants(a.variant), a.cache, a.analyse_only,
             a.first_seed, a.reference_only)
    else:
        cost_curve(a.n, a.duration, a.seed, a.set)
    return 0


if __name__ == "__main__":
    sys.exit(main())
