"""Why SUMO's own step costs more CPU in a V2X merging run than in the ``human`` run: SUMO's
``simulationStep`` CPU of one merging run (seed, duration) in each of these set-ups, each in a fresh
process (libsumo: one simulation per process), the set-ups alternating round by round:

- ``human``: the human baseline (no controller);
- ``idle``: the ``v2x_cps`` variant with its controller set up (channel, tracks, compiled kernels
  loaded) but its tick a no-op: what the V2X variant's scenario asks of SUMO by itself;
- ``discard``: ``v2x_cps`` with the controller's full tick and its commands discarded (SUMO drives the
  ``human`` run's traffic, the controller's work between two steps unchanged);
- ``v2x``: ``v2x_cps`` as it runs;
- ``busy``: the ``human`` run with ``--busy-loops`` iterations of a Python integer loop after each
  step (CPU between two steps on next to no data);
- ``touch``: the ``human`` run with a ``--touch-mib`` MiB array written after each step (memory traffic).

The vehicle-steps are printed too: the same as ``human`` means SUMO simulated the same traffic.

    python benchmarks/v2x_sumo_step.py [--duration 300] [--seed 0] [--rounds 2] [--modes human idle ...]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
MODES = ("human", "idle", "discard", "v2x", "busy", "touch")


def one_run(mode: str, seed: int, duration: float, busy_loops: int, touch_mib: float) -> str:
    """One run in this process: its tick loop's CPU, SUMO's step CPU and the vehicle-steps, as a line."""
    import libsumo
    import numpy as np

    from corridor.batch import expand
    from corridor.controllers.merging.components import V2XMerging
    from corridor.run import build
    from corridor.scenario import apply_overrides, load, validate
    from corridor.traffic.sumo.backend import SumoBackend

    variant = "human" if mode in ("human", "busy", "touch") else "v2x_cps"
    path = ROOT / "scenarios" / "merging.yaml"
    sc, raw = load(path, [f"duration={duration}", "warmup=0", "outputs.signals=false"])
    spec = next(s for s in expand(sc, raw, str(path), seed + 1, variants=[variant]) if s.seed == seed)
    vsc = validate(apply_overrides(spec.base, spec.overrides), spec.run_id)
    step_cpu = [0.0]
    step = libsumo.simulationStep

    def timed_step(*a: Any) -> Any:
        t0 = time.process_time()
        try:
            return step(*a)
        finally:
            step_cpu[0] += time.process_time() - t0

    libsumo.simulationStep = timed_step  # the backend calls it through the module
    if mode == "discard":
        SumoBackend.apply = lambda self, commands, ctx: None  # type: ignore[method-assign]
    if mode == "idle":
        V2XMerging.tick = lambda self, ctx: None  # type: ignore[method-assign]
    block = np.zeros(int(touch_mib * 2**20) // 8) if mode == "touch" else None
    with tempfile.TemporaryDirectory(prefix="corridor-bench-") as tmp:
        sim = build(vsc, seed, Path(tmp))
        ctx = sim.ctx
        try:
            for c in sim.setup_order:
                c.setup(ctx)
            t0 = time.process_time()
            for _ in range(round(ctx.duration / ctx.dt)):
                sim.step()
                if mode == "busy":
                    x = 0
                    for i in range(busy_loops):
                        x += i
                elif block is not None:
                    block += 1.0
            loop = time.process_time() - t0
        finally:
            for c in ctx.components.values():
                c.close()
    _, n = ctx.signals.get("vehicles")
    return f"{mode:8s} tick loop {loop:5.2f} s | SUMO step {step_cpu[0]:5.2f} s | vehicle-steps {int(n.sum())}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--busy-loops", type=int, default=12000, help="Python loop iterations after each step (busy)")
    ap.add_argument("--touch-mib", type=float, default=2.0, help="MiB written after each step (touch)")
    ap.add_argument("--one", choices=MODES, help=argparse.SUPPRESS)  # a single run in this process
    args = ap.parse_args()
    if args.one:
        print(one_run(args.one, args.seed, args.duration, args.busy_loops, args.touch_mib))
        return
    for r in range(args.rounds):
        for mode in args.modes:
            out = subprocess.run([sys.executable, __file__, "--one", mode, "--seed", str(args.seed),
                                  "--duration", str(args.duration), "--busy-loops", str(args.busy_loops),
                                  "--touch-mib", str(args.touch_mib)], capture_output=True, text=True, check=True)
            print(f"round {r}: {out.stdout.strip()}", flush=True)


if __name__ == "__main__":
    main()
