"""Where the time of ``scenarios/air_ground_watch.yaml`` goes: CPU seconds per component, per variant.

    python benchmarks/air_ground_watch_time.py [--duration 120] [--variant loops ...]

Runs each variant once in this process (seed 0) and prints the wall time per simulated second, the
CPU time per simulated second, and each component's share of the CPU time of the ticks (set-up:
network build, JSBSim loading, excluded), plus the snapshot assembly.  The ``loops`` variant (SUMO +
MPC, no aircraft) is the baseline measured in the same run: the ratio column is each variant's CPU
per simulated second against it.  Not run by CI; on a shared machine read the ratios, not the
absolute figures.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from corridor.run import build
from corridor.scenario import apply_overrides, load, validate

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "air_ground_watch.yaml"


def measure(variant: str, duration_s: float) -> tuple[float, float, dict[str, float]]:
    """(wall s, CPU s, CPU s per component) of the ticks of one run."""
    _, raw = load(SCENARIO, [f"duration={duration_s}", "outputs.signals=false"])
    sc = validate(apply_overrides(raw, raw["sweep"][variant]), str(SCENARIO))
    scratch = tempfile.TemporaryDirectory(prefix="corridor-bench-")  # SUMO writes routes.rou.xml there
    sim = build(sc, 0, Path(scratch.name))
    for c in sim.setup_order:
        c.setup(sim.ctx)
    cpu: dict[str, float] = {}
    for c in sim.ctx.components.values():
        def timed(ctx, _tick=c.tick, _name=c.name):  # noqa: ANN001, ANN202
            t0 = time.process_time()
            _tick(ctx)
            cpu[_name] = cpu.get(_name, 0.0) + time.process_time() - t0
        c.tick = timed  # type: ignore[method-assign]
    integrate = sim._integrate

    def snapshot() -> None:
        t0 = time.process_time()
        integrate()
        cpu["(integrate + snapshot)"] = cpu.get("(integrate + snapshot)", 0.0) + time.process_time() - t0

    sim._integrate = snapshot  # type: ignore[method-assign]
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(round(sc.duration / sc.dt)):
        sim.step()
    wall, total = time.perf_counter() - w0, time.process_time() - c0
    for c in sim.ctx.components.values():
        c.finish(sim.ctx)
        c.close()
    scratch.cleanup()
    backends = sum(v for k, v in cpu.items() if k in ("road", "air"))
    cpu["(integrate + snapshot)"] -= backends  # the backends' own ticks are listed by name
    return wall, total, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--variant", action="append")
    args = ap.parse_args()
    variants = args.variant or ["loops", "loops_failed_uav_pf", "loops_failed_uav_ct"]
    if "loops" not in variants:
        variants = ["loops", *variants]
    base = None
    for v in variants:
        wall, total, cpu = measure(v, args.duration)
        per_s = total / args.duration
        base = base or per_s
        print(f"{v}: wall {wall / args.duration:.3f} s per simulated s, CPU {per_s:.3f} s per simulated s "
              f"(x{per_s / base:.2f} of loops)")
        for name, sec in sorted(cpu.items(), key=lambda kv: -kv[1])[:10]:
            print(f"    {name:<24s} {100 * sec / total:5.1f} %")


if __name__ == "__main__":
    main()
