"""Real-time factor of ``scenarios/uav_swarm.yaml`` per variant (sim seconds / wall seconds).

    python benchmarks/uav_swarm_rtf.py [--n 20] [--duration 30] [--variant none ...] [--repeat 3]

Runs the swarm (JSBSim at 120 Hz, MAVLink link, tracking, avoidance, separation monitor) once per
variant in this process and prints, per variant, the wall-clock RTF and the CPU-time RTF (sim
seconds / process CPU seconds: what the run would reach on an idle core of this machine), the set-up
time (JSBSim loading, excluded from both), the Kalman updates per simulated second (``KF/s``: reports
fused by the link's trackers) and the per-phase share of the CPU time. With
``--repeat N`` each variant runs N times (interleaved with the other variants) and the fastest run
is reported, as ``timeit`` does: on a shared machine the CPU time of a run also rises with what the
other processes do to the caches and the sibling hyper-thread. Not run by CI.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from corridor.engine import Phase
from corridor.run import build
from corridor.scenario import apply_overrides, load, validate

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "uav_swarm.yaml"


def measure(variant: str, n: int, duration_s: float) -> dict[str, float]:
    """Build and run one variant; returns RTFs, set-up time and CPU seconds per phase."""
    sc, raw = load(SCENARIO, [f"backends.air.params.swarm.n={n}", f"duration={duration_s}"])
    sc = validate(apply_overrides(raw, sc.sweep[variant]), str(SCENARIO))
    sim = build(sc, 0, Path("."))
    c0 = time.process_time()
    for c in sim.ctx.components.values():
        c.setup(sim.ctx)
    setup_cpu = time.process_time() - c0
    per_phase = dict.fromkeys(Phase, 0.0)
    original = sim._run

    def timed(phase: Phase) -> None:
        t = time.process_time()
        original(phase)
        per_phase[phase] += time.process_time() - t

    sim._run = timed  # measurement only: the same calls in the same order
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(round(sc.duration / sc.dt)):
        sim.step()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    metrics: dict[str, float] = {}
    for c in sim.ctx.components.values():
        metrics.update(c.finish(sim.ctx))
        c.close()
    return {"rtf_wall": sc.duration / wall, "rtf_cpu": sc.duration / cpu, "setup_cpu_s": setup_cpu,
            "nmac": metrics.get("nmac", float("nan")),
            "fused_per_s": metrics.get("link_fused_reports", 0.0) / sc.duration,
            **{f"cpu_{p.name.lower()}": per_phase[p] / cpu for p in Phase}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="quadcopters (default 20)")
    ap.add_argument("--duration", type=float, default=30.0, help="simulated seconds per variant")
    ap.add_argument("--variant", action="append", default=None, help="none | potential_field | control_tube")
    ap.add_argument("--repeat", type=int, default=1, help="runs per variant; the fastest (CPU) is reported")
    args = ap.parse_args()
    variants = args.variant or ["none", "potential_field", "control_tube"]
    print(f"uav_swarm: {args.n} F450 quadcopters, {args.duration:.0f} s simulated per variant"
          + (f", best of {args.repeat}" if args.repeat > 1 else ""))
    runs: dict[str, list[dict[str, float]]] = {v: [] for v in variants}
    for _ in range(args.repeat):
        for v in variants:
            runs[v].append(measure(v, args.n, args.duration))
    print(f"{'variant':<16} {'RTF wall':>9} {'RTF cpu':>8} {'setup s':>8} {'nmac':>5} {'KF/s':>5}  cpu share by phase")
    for v in variants:
        r = max(runs[v], key=lambda x: x["rtf_cpu"])
        shares = " ".join(f"{p.name.lower()[:5]}={r[f'cpu_{p.name.lower()}']:.0%}" for p in Phase
                          if r[f"cpu_{p.name.lower()}"] >= 0.005)
        print(f"{v:<16} {r['rtf_wall']:>8.2f}x {r['rtf_cpu']:>7.2f}x {r['setup_cpu_s']:>8.1f} {r['nmac']:>5.0f}"
              f" {r['fused_per_s']:>5.0f}  {shares}",
              flush=True)


if __name__ == "__main__":
    main()
