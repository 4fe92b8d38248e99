"""Cost of V2X merging: CPU time of a ``v2x_fifo`` and a ``v2x_cps`` merging run divided by that of the
human baseline run (``human``: the calibrated humans, no controller) on the same seeds (the same demand
draws, SUMO seed and vehicles), in one process run.  The old baseline (``sumo_default``, SUMO's Krauss
drivers) is timed too: ``--baseline sumo_default`` divides by it instead.

Times are CPU times of this process's tick loops (``time.process_time``, set-up excluded), so the
ratio holds on a machine shared with other work; the two variants alternate seed by seed.

    python benchmarks/v2x_cost.py [--duration 300] [--seeds 2] [--repeat 1]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from kernel_overhead import corridor_run  # this folder is on sys.path when run as a script

from corridor.batch import expand
from corridor.scenario import apply_overrides, load, validate

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("human", "sumo_default", "v2x_fifo", "v2x_cps")
COOPERATIVE = ("v2x_fifo", "v2x_cps")


def tick_loop_cpu(sc, seed: int) -> float:
    """CPU seconds of the run's tick loop (after every component's set-up): kernel_overhead's loop."""
    return corridor_run(sc, seed)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "merging.yaml"))
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="rounds over the seeds (best per run is kept)")
    ap.add_argument("--baseline", default="human", choices=["human", "sumo_default"], help="the denominator")
    args = ap.parse_args()
    # warm-up only decides what the monitors count, not what runs: 0 lets any --duration through
    sc, raw = load(args.scenario, [f"duration={args.duration}", "warmup=0", "outputs.signals=false"])
    plan = expand(sc, raw, args.scenario, args.seeds, variants=list(VARIANTS))
    runs = [(s.variant, s.seed, validate(apply_overrides(s.base, s.overrides), s.run_id)) for s in plan]
    tick_loop_cpu(runs[0][2], runs[0][1])  # warm the network cache and imports
    best: dict[tuple[str, int], float] = {}
    for _ in range(args.repeat):
        for variant, seed, vsc in runs:
            cpu = tick_loop_cpu(vsc, seed)
            best[variant, seed] = min(cpu, best.get((variant, seed), cpu))
    b = args.baseline
    for seed in sorted({s for _, s in best}):
        print(f"seed {seed}: " + " | ".join(f"{v} {best[v, seed]:.2f} s CPU" for v in VARIANTS)
              + "".join(f" | {v} / {b} {best[v, seed] / best[b, seed]:.2f}" for v in COOPERATIVE))
    total = {v: sum(t for (w, _), t in best.items() if w == v) for v in VARIANTS}
    for v in COOPERATIVE:
        print(f"{args.seeds} seeds x {args.duration:g} s simulated: {v} CPU / {b} CPU = "
              f"{total[v] / total[b]:.2f}x (CPU per simulated second: {total[v] / (args.seeds * args.duration) * 1e3:.1f} ms"
              f" against {total[b] / (args.seeds * args.duration) * 1e3:.1f} ms; issue 27's target <= 1.5x)")


if __name__ == "__main__":
    main()
