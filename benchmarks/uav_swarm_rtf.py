"""Real-time factor of ``scenarios/uav_swarm.yaml`` per variant and swarm size, against raw JSBSim.

    python benchmarks/uav_swarm_rtf.py            # 20-quad table (3 variants) + curve N = 5 ... 200
    python benchmarks/uav_swarm_rtf.py --quick    # the same rows, shorter runs and fewer sizes (make bench)
    python benchmarks/uav_swarm_rtf.py --n 80 --variant potential_field --duration 30 --no-curve

Every figure is a real-time factor by CPU time: simulated seconds per process CPU second of the
stepping loop (JSBSim model loading excluded), i.e. what the run would reach on an idle core. The
anchor, measured in the same run for the same N and duration, is raw JSBSim: N of the wheel's F450
(its own rate loops engaged, constant sticks, no corridor code), each stepped its 12 sub-steps of a
0.1 s tick in a row. ``÷raw`` is corridor's figure over the anchor: the share of the JSBSim floor
that the whole scenario (MAVLink link, trackers, avoidance, monitors) keeps. The table also shows the
wall-clock factor, Kalman updates per simulated second (``KF/s``) and each phase's share of the CPU.
With ``--repeat N`` each measurement runs N times (interleaved) and the fastest is kept, as ``timeit``
does: on a shared machine the CPU time of a run also rises with what the other processes do to the
caches and the sibling hyper-thread. Not run by CI; ``make bench`` runs ``--quick``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import jsbsim

from corridor.engine import Phase
from corridor.run import build
from corridor.scenario import apply_overrides, load, validate
from corridor.vehicles.air.jsbsim_fleet import JSBSimLogSink, quiet_fds

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "uav_swarm.yaml"
VARIANTS = ("none", "potential_field", "control_tube")
CURVE_VARIANTS = ("none", "potential_field")


def measure(variant: str, n: int, duration_s: float) -> dict[str, float]:
    """Build and run one variant; returns RTFs, set-up time and CPU seconds per phase."""
    sc, raw = load(SCENARIO, [f"backends.air.params.swarm.n={n}", f"duration={duration_s}"])
    sc = validate(apply_overrides(raw, sc.sweep[variant]), str(SCENARIO))
    scratch = tempfile.TemporaryDirectory(prefix="corridor-bench-")  # SUMO writes routes.rou.xml there
    sim = build(sc, 0, Path(scratch.name))
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
    scratch.cleanup()
    return {"rtf_wall": sc.duration / wall, "rtf_cpu": sc.duration / cpu, "setup_cpu_s": setup_cpu,
            "nmac": metrics.get("nmac", float("nan")),
            "fused_per_s": metrics.get("link_fused_reports", 0.0) / sc.duration,
            **{f"cpu_{p.name.lower()}": per_phase[p] / cpu for p in Phase}}


def raw_jsbsim(n: int, duration_s: float, rate_hz: float = 120.0, tick_s: float = 0.1) -> dict[str, float]:
    """The anchor: ``n`` wheel F450s (rate loops engaged, hover collective, 60 m up), each stepped a
    tick's sub-steps in a row, for ``duration_s``; RTF by CPU time and CPU microseconds per step."""
    sink = JSBSimLogSink()
    jsbsim.set_logger(sink)
    root = jsbsim.get_default_root_dir()
    fdms = []
    for _ in range(n):
        with quiet_fds():
            fdm = jsbsim.FGFDMExec(root)
            fdm.set_debug_level(0)
            fdm.load_model("F450")
            fdm.set_dt(1.0 / rate_hz)
            fdm["ic/h-agl-ft"] = 200.0  # otherwise the F450 starts 285 m high
            fdm.run_ic()
        fdm["fcs/ScasEngage"] = 1.0
        fdm["fcs/throttle-cmd-norm"] = 0.42
        fdms.append(fdm)
    runs: list[Callable[[], bool]] = [f.run for f in fdms]
    sub = round(tick_s * rate_hz)
    ticks = round(duration_s / tick_s)
    c0 = time.process_time()
    for _ in range(ticks):
        for run in runs:
            for _ in range(sub):
                run()
    cpu = time.process_time() - c0
    return {"rtf_cpu": duration_s / cpu, "us_per_step": 1e6 * cpu / (ticks * sub * n)}


def best(fn: Callable[[], dict[str, float]], repeat: int) -> dict[str, float]:
    return max((fn() for _ in range(repeat)), key=lambda r: r["rtf_cpu"])


def table(n: int, duration_s: float, variants: list[str], repeat: int) -> None:
    anchor = best(lambda: raw_jsbsim(n, duration_s), repeat)
    runs = {v: best(lambda v=v: measure(v, n, duration_s), repeat) for v in variants}
    print(f"\n{n} F450 quadcopters, {duration_s:g} s simulated; raw JSBSim anchor {anchor['rtf_cpu']:.1f}x "
          f"({anchor['us_per_step']:.1f} us per aircraft step)")
    print(f"{'variant':<16} {'RTF wall':>9} {'RTF cpu':>8} {'÷raw':>5} {'setup s':>8} {'nmac':>5} {'KF/s':>5}"
          "  cpu share by phase")
    for v, r in runs.items():
        shares = " ".join(f"{p.name.lower()[:5]}={r[f'cpu_{p.name.lower()}']:.0%}" for p in Phase
                          if r[f"cpu_{p.name.lower()}"] >= 0.005)
        print(f"{v:<16} {r['rtf_wall']:>8.2f}x {r['rtf_cpu']:>7.2f}x {r['rtf_cpu'] / anchor['rtf_cpu']:>5.2f}"
              f" {r['setup_cpu_s']:>8.1f} {r['nmac']:>5.0f} {r['fused_per_s']:>5.0f}  {shares}", flush=True)


def curve(sizes: list[int], duration_s: float, repeat: int) -> None:
    """RTF by CPU time against N for the curve variants, each beside the raw-JSBSim anchor."""
    print(f"\nscaling, {duration_s:g} s simulated per point (RTF by CPU time; ÷raw = share of the anchor)")
    head = "".join(f" {v[:15]:>15} {'÷raw':>5}" for v in CURVE_VARIANTS)
    print(f"{'N':>4} {'raw JSBSim':>10} {'us/step':>7}{head}")
    largest = dict.fromkeys(CURVE_VARIANTS, 0)
    for n in sizes:
        anchor = best(lambda n=n: raw_jsbsim(n, duration_s), repeat)
        row = f"{n:>4} {anchor['rtf_cpu']:>9.1f}x {anchor['us_per_step']:>7.1f}"
        for v in CURVE_VARIANTS:
            r = best(lambda v=v, n=n: measure(v, n, duration_s), repeat)
            row += f" {r['rtf_cpu']:>14.2f}x {r['rtf_cpu'] / anchor['rtf_cpu']:>5.2f}"
            if r["rtf_cpu"] >= 1.0:
                largest[v] = max(largest[v], n)
        print(row, flush=True)
    print("largest N at >= 1x real time (CPU): " + ", ".join(f"{v} {largest[v]}" for v in CURVE_VARIANTS))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs, fewer sizes (make bench)")
    ap.add_argument("--n", type=int, default=20, help="quadcopters of the variant table (default 20)")
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds per run (30; quick 8)")
    ap.add_argument("--variant", action="append", default=None, help="none | potential_field | control_tube")
    ap.add_argument("--sizes", type=str, default=None, help="curve sizes, e.g. 5,20,100")
    ap.add_argument("--no-curve", action="store_true", help="only the variant table")
    ap.add_argument("--repeat", type=int, default=1, help="runs per point; the fastest (CPU) is reported")
    args = ap.parse_args()
    duration = args.duration or (8.0 if args.quick else 30.0)
    default_sizes = "5,20,50,100,200" if args.quick else "5,10,20,40,60,80,100,120,160,200"
    print(f"uav_swarm real-time factors by CPU time{' (quick)' if args.quick else ''}"
          + (f", best of {args.repeat}" if args.repeat > 1 else ""))
    table(args.n, duration, args.variant or list(VARIANTS), args.repeat)
    if not args.no_curve:
        curve([int(s) for s in (args.sizes or default_sizes).split(",")], duration, args.repeat)


if __name__ == "__main__":
    main()
