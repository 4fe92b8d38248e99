"""Cost of V2X merging: CPU time of each cooperative variant's run divided by that of its human baseline
run on the same seeds (the same demand draws, SUMO seed and vehicles), in one process run.

``scenarios/merging.yaml`` (the default): ``v2x_fifo`` and ``v2x_cps`` against ``human`` (the calibrated
humans, no controller); the old baseline (``sumo_default``, SUMO's Krauss drivers) is timed too:
``--baseline sumo_default`` divides by it instead.  Any other scenario (``scenarios/flow_merge.yaml``):
every variant with a controller is cooperative, and its baseline is the variant without one that has
the same other overrides (connected shares aside): on flow_merge ``merge0-2`` against ``human`` and
``cal_merge0-2``, ``cal_all*_ramp`` against ``human_cal``.  ``--variants`` times a subset (their
baselines are added), ``--baseline`` names one baseline for all.

Times are CPU times of this process's tick loops (``time.process_time``, set-up excluded), so the
ratio holds on a machine shared with other work; the variants alternate seed by seed.

    python benchmarks/v2x_cost.py [--scenario scenarios/merging.yaml] [--duration 300] [--seeds 2] [--repeat 1]
    python benchmarks/v2x_cost.py --scenario scenarios/flow_merge.yaml --duration 750 --seeds 1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from kernel_overhead import corridor_run  # this folder is on sys.path when run as a script

from corridor.batch import expand
from corridor.scenario import apply_overrides, load, validate

ROOT = Path(__file__).resolve().parents[1]
MERGING = "merging"  # the flagship: its variants and columns as before
VARIANTS = ("human", "sumo_default", "v2x_fifo", "v2x_cps")
COOPERATIVE = ("v2x_fifo", "v2x_cps")
WARM_S = 60.0  # [s] simulated per variant before the timed runs (long enough for the zone to fill)


def tick_loop_cpu(sc, seed: int) -> float:
    """CPU seconds of the run's tick loop (after every component's set-up): kernel_overhead's loop."""
    return corridor_run(sc, seed)[0]


def _cooperative(overrides: dict[str, Any]) -> bool:
    return any(k == "controllers" or k.startswith("controllers.") for k in overrides)


def _rest(overrides: dict[str, Any]) -> dict[str, Any]:
    """The overrides that make a cooperative variant's humans: no controller, no connected share."""
    return {k: v for k, v in overrides.items()
            if not (k == "controllers" or k.startswith("controllers.") or k.endswith(".connected_share"))}


def pairs(sweep: dict[str, dict[str, Any]], baseline: str | None = None) -> dict[str, str]:
    """Cooperative variant -> its baseline variant (``baseline`` if given; else the variant without a
    controller whose other overrides, connected shares aside, are the same)."""
    out = {}
    for v, ov in sweep.items():
        if not _cooperative(ov):
            continue
        if baseline is not None:
            out[v] = baseline
            continue
        same = [b for b, bo in sweep.items() if not _cooperative(bo) and _rest(bo) == _rest(ov)]
        if not same:
            raise SystemExit(f"v2x_cost: no baseline variant for {v!r} (a variant without a controller and "
                             "the same other overrides); name one with --baseline")
        out[v] = same[0]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "merging.yaml"))
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="rounds over the seeds (best per run is kept)")
    ap.add_argument("--baseline", default=None,
                    help="the denominator for every variant (merging: human or sumo_default; default: derived)")
    ap.add_argument("--variants", default=None, help="comma-separated cooperative variants (default: all)")
    args = ap.parse_args()
    # warm-up only decides what the monitors count, not what runs: 0 lets any --duration through
    sc, raw = load(args.scenario, [f"duration={args.duration}", "warmup=0", "outputs.signals=false"])
    if args.baseline is not None and args.baseline not in sc.sweep:
        print(f"v2x_cost: --baseline {args.baseline!r}: not a variant of {args.scenario} "
              f"({', '.join(sc.sweep)})", file=sys.stderr)
        raise SystemExit(2)
    flagship = sc.name == MERGING and set(VARIANTS) <= set(sc.sweep) and args.variants is None
    if flagship:
        timed, coop = VARIANTS, {v: args.baseline or "human" for v in COOPERATIVE}
    else:
        coop = pairs(sc.sweep, args.baseline)
        if args.variants is not None:
            wanted = [v.strip() for v in args.variants.split(",") if v.strip()]
            unknown = [v for v in wanted if v not in coop]
            if unknown:
                print(f"v2x_cost: --variants {unknown[0]!r}: not a cooperative variant of {args.scenario} "
                      f"({', '.join(coop)})", file=sys.stderr)
                raise SystemExit(2)
            coop = {v: coop[v] for v in wanted}
        if not coop:
            print(f"v2x_cost: {args.scenario} has no cooperative variant (one with a controller)", file=sys.stderr)
            raise SystemExit(2)
        timed = tuple(v for v in sc.sweep if v in coop or v in coop.values())
    plan = expand(sc, raw, args.scenario, args.seeds, variants=list(timed))
    runs = [(s.variant, s.seed, validate(apply_overrides(s.base, s.overrides), s.run_id)) for s in plan]
    # warm the network cache, the imports and every timed variant's code (a kernel compiled or loaded from
    # numba's cache on first use would otherwise land in the first run of its variant): one short run each
    wsc, wraw = load(args.scenario, [f"duration={min(args.duration, WARM_S)}", "warmup=0", "outputs.signals=false"])
    for s in expand(wsc, wraw, args.scenario, 1, variants=list(timed)):
        tick_loop_cpu(validate(apply_overrides(s.base, s.overrides), s.run_id), s.seed)
    best: dict[tuple[str, int], float] = {}
    for _ in range(args.repeat):
        for variant, seed, vsc in runs:
            cpu = tick_loop_cpu(vsc, seed)
            best[variant, seed] = min(cpu, best.get((variant, seed), cpu))
    for seed in sorted({s for _, s in best}):
        print(f"seed {seed}: " + " | ".join(f"{v} {best[v, seed]:.2f} s CPU" for v in timed)
              + "".join(f" | {v} / {b} {best[v, seed] / best[b, seed]:.2f}" for v, b in coop.items()))
    total = {v: sum(t for (w, _), t in best.items() if w == v) for v in timed}
    sim_s = args.seeds * args.duration
    for v, b in coop.items():
        print(f"{args.seeds} seeds x {args.duration:g} s simulated: {v} CPU / {b} CPU = "
              f"{total[v] / total[b]:.2f}x (CPU per simulated second: {total[v] / sim_s * 1e3:.2f} ms"
              f" against {total[b] / sim_s * 1e3:.2f} ms; issue 27's target <= 1.5x)")


if __name__ == "__main__":
    main()
