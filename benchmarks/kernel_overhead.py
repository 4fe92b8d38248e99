"""Kernel overhead: the same network and demand as a bare libsumo loop and as a corridor run
(snapshot + monitors on), in one process run.  Prints vehicle-steps/s of both and their ratio.

Times are CPU times of this process (``time.process_time``: everything here is single-threaded), so
the ratios hold on a machine shared with other work; the loops alternate and the best of
``--repeat`` rounds is taken for each.

    python benchmarks/kernel_overhead.py [--duration 600] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from corridor.engine import RunContext
from corridor.run import build
from corridor.scenario import load
from corridor.traffic.sumo.backend import SumoBackend, sumo_seed
from corridor.traffic.sumo.road_spec import road_spec

ROOT = Path(__file__).resolve().parents[1]


def bare_libsumo(sc, seed: int, read_state: str = "") -> tuple[float, int]:
    """Build the same network/routes through the backend's own helpers, then a plain step loop;
    with ``read_state`` it also subscribes the same six vehicle variables and reads them into numpy
    arrays each step (what a hand-written libsumo script needs to do anything with the state):
    ``"rows"`` by one ``np.array`` over a list of row tuples (the anchor of the target), ``"columns"``
    by one ``np.fromiter`` per variable (corridor's own way, ~3x cheaper than rows)."""
    from itertools import chain
    from operator import itemgetter

    import libsumo
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        backend = SumoBackend("road", road_spec(sc), sc)
        ctx = RunContext(run_seed=seed, dt=sc.dt, duration=sc.duration, scenario=sc, workdir=Path(tmp))
        routes = backend._write_demand(ctx)
        libsumo.start(backend._args(routes, sumo_seed(seed), sc.duration))  # the corridor run's traffic
        steps = round(sc.duration / backend.road.sumo.step_length)
        vehicle_steps = 0
        t0 = time.process_time()
        ls = libsumo
        var = (ls.VAR_POSITION, ls.VAR_SPEED, ls.VAR_ANGLE, ls.VAR_ACCELERATION, ls.VAR_LANE_ID, ls.VAR_LANEPOSITION)
        if read_state:
            ls.simulation.subscribe([ls.VAR_DEPARTED_VEHICLES_IDS])
        for _ in range(steps):
            libsumo.simulationStep()
            if read_state:
                for vid in ls.simulation.getSubscriptionResults()[ls.VAR_DEPARTED_VEHICLES_IDS]:
                    ls.vehicle.subscribe(vid, var)
                res = ls.vehicle.getAllSubscriptionResults()
                rows = list(res.values())
                if read_state == "rows":
                    np.array([(*r[var[0]], r[var[1]], r[var[2]], r[var[3]], r[var[5]]) for r in rows], dtype=float)
                else:
                    n = len(rows)
                    np.fromiter(chain.from_iterable(map(itemgetter(var[0]), rows)), dtype=float, count=2 * n)
                    for k in (var[1], var[2], var[3], var[5]):
                        np.fromiter(map(itemgetter(k), rows), dtype=float, count=n)
                vehicle_steps += len(rows)
            else:
                vehicle_steps += libsumo.vehicle.getIDCount()
        cpu = time.process_time() - t0
        libsumo.close()
    return cpu, vehicle_steps


def corridor_run(sc, seed: int) -> tuple[float, int]:
    """CPU time of the tick loop and the components' ``finish`` (after set-up and SUMO's start, as
    the bare loops time theirs) and the vehicle-steps."""
    with tempfile.TemporaryDirectory(prefix="corridor-bench-") as tmp:
        sim = build(sc, seed, Path(tmp))
        ctx = sim.ctx
        try:
            for c in sim.setup_order:
                c.setup(ctx)
            t0 = time.process_time()
            for _ in range(round(ctx.duration / ctx.dt)):
                sim.step()
            for c in ctx.components.values():  # timed too: monitors that work in blocks of ticks
                c.finish(ctx)  # process their last block here
            cpu = time.process_time() - t0
        finally:
            for c in ctx.components.values():
                c.close()
    _, n = ctx.signals.get("vehicles")
    return cpu, int(n.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "merging.yaml"))
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sc, _ = load(args.scenario, [f"duration={args.duration}", "warmup=0", "outputs.signals=false"])
    corridor_run(sc, 0)  # warm the network cache and imports
    rows = []
    for r in range(args.repeat):  # one seed per round
        bw, bn = bare_libsumo(sc, r)
        sw, sn = bare_libsumo(sc, r, read_state="rows")
        cw, cn = corridor_run(sc, r)
        kw, _ = bare_libsumo(sc, r, read_state="columns")
        rows.append((bw, bn, sw, sn, cw, cn, kw))
        print(f"repeat {r}: bare step loop {bn / bw:,.0f} veh-steps/s ({bw:.2f} s) | bare + state read "
              f"{sn / sw:,.0f} ({sw:.2f} s) | corridor {cn / cw:,.0f} ({cw:.2f} s) | bare + column read "
              f"({kw:.2f} s)")
    # per round the three loops simulate the same traffic (one seed); each ratio is taken within a round
    step_ratio = statistics.median(r[4] / r[0] for r in rows)
    read_ratio = statistics.median(r[4] / r[2] for r in rows)
    column_ratio = statistics.median(r[4] / r[6] for r in rows)
    bw, bn, sw, sn, cw, cn = (sum(r[i] for r in rows) for i in range(6))
    print(f"\nall {args.repeat} rounds (vehicle-steps per CPU second): bare libsumo step loop {bn / bw:,.0f}; "
          f"bare libsumo + subscribed state read {sn / sw:,.0f}; corridor (snapshot + monitors) {cn / cw:,.0f}")
    print(f"corridor / bare step loop:        {step_ratio:.2f}x CPU time (median of the rounds)")
    print(f"corridor / bare loop + state read: {read_ratio:.2f}x CPU time (median of the rounds; target <= 1.25)")
    print(f"corridor / bare loop + column read: {column_ratio:.2f}x CPU time (median; the same read, corridor's "
          f"gather: the stricter anchor)")


if __name__ == "__main__":
    main()
