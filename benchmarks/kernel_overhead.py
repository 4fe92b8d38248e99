"""Kernel overhead: the same network and demand as a bare libsumo loop and as a corridor run
(snapshot + monitors on), in one process run.  Prints vehicle-steps/s of both and their ratio.

    python benchmarks/kernel_overhead.py [--duration 600] [--repeat 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from corridor.engine import RunContext
from corridor.run import simulate
from corridor.scenario import load
from corridor.traffic.road_spec import road_spec
from corridor.traffic.sumo_backend import SumoBackend

ROOT = Path(__file__).resolve().parents[1]


def bare_libsumo(sc, seed: int, read_state: bool = False) -> tuple[float, int]:
    """Build the same network/routes through the backend's own helpers, then a plain step loop;
    with ``read_state`` it also subscribes the same six vehicle variables and reads them into numpy
    arrays each step (what a hand-written libsumo script needs to do anything with the state)."""
    import libsumo
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        backend = SumoBackend("road", road_spec(sc), sc)
        ctx = RunContext(run_seed=seed, dt=sc.dt, duration=sc.duration, scenario=sc, workdir=Path(tmp))
        routes = backend._write_demand(ctx)
        libsumo.start(backend._args(routes, 12345, sc.duration))
        steps = round(sc.duration / backend.road.sumo.step_length)
        vehicle_steps = 0
        t0 = time.perf_counter()
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
                np.array([(*r[var[0]], r[var[1]], r[var[2]], r[var[3]], r[var[5]]) for r in rows], dtype=float)
                vehicle_steps += len(rows)
            else:
                vehicle_steps += libsumo.vehicle.getIDCount()
        wall = time.perf_counter() - t0
        libsumo.close()
    return wall, vehicle_steps


def corridor_run(sc, seed: int) -> tuple[float, int]:
    metrics, ctx, wall = simulate(sc, seed)
    _, n = ctx.signals.get("vehicles")
    return wall, int(n.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "merging.yaml"))
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    sc, _ = load(args.scenario, [f"duration={args.duration}", "warmup=0", "outputs.signals=false"])
    corridor_run(sc, 0)  # warm the network cache and imports
    rows = []
    for r in range(args.repeat):
        bw, bn = bare_libsumo(sc, r)
        sw, sn = bare_libsumo(sc, r, read_state=True)
        cw, cn = corridor_run(sc, r)
        rows.append((bw, bn, sw, sn, cw, cn))
        print(f"repeat {r}: bare step loop {bn / bw:,.0f} veh-steps/s ({bw:.2f} s) | bare + state read "
              f"{sn / sw:,.0f} ({sw:.2f} s) | corridor {cn / cw:,.0f} ({cw:.2f} s)")
    bw, sw, cw = (min(r[i] for r in rows) for i in (0, 2, 4))
    bn, sn, cn = rows[0][1], rows[0][3], rows[0][5]
    print(f"\nbest of {args.repeat} (vehicle-steps/s): bare libsumo step loop {bn / bw:,.0f}; bare libsumo + "
          f"subscribed state read {sn / sw:,.0f}; corridor (snapshot + monitors) {cn / cw:,.0f}")
    print(f"corridor / bare step loop:        {cw / bw:.2f}x wall time")
    print(f"corridor / bare loop + state read: {cw / sw:.2f}x wall time")


if __name__ == "__main__":
    main()
