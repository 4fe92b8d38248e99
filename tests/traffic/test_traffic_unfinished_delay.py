"""Delay counts vehicles that had not finished: a jammed road must not look better than a free one."""

from __future__ import annotations

import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "merging.yaml"


def _delays_at_double_demand() -> dict[str, object]:
    from corridor.run import build
    from corridor.scenario import load

    sc, _ = load(str(SCENARIO), ["duration=150", "warmup=0", "road.demand.scale=2.0"])
    sim = build(sc, 0, Path(tempfile.mkdtemp()))
    ctx = sim.ctx
    for c in ctx.components.values():
        c.setup(ctx)
    try:
        for _ in range(round(sc.duration / sc.dt)):
            sim.step()
        trips = ctx.components["trips"]
        done = trips.delays(0.0)
        allv = trips.delays(0.0, unfinished=True)
        n_arrived = int(np.count_nonzero(~np.isnan(trips.arrive_s[:trips.n_departed])))
        _, on_road = ctx.signals.get("vehicles")
        return {"tts_vh": ctx.components["kpis"].tts_vh, "on_road_vh": float(np.sum(on_road)) * sc.dt / 3600.0,
                "duration_h": sc.duration / 3600.0,"done": done, "all": allv, "backlog": trips.backlog(), "n_active": len(ctx.snapshot.road),
                "n_arrived": n_arrived, "t": ctx.t}
    finally:
        for c in ctx.components.values():
            c.close()


def test_unfinished_and_waiting_vehicles_are_counted_with_their_delay_so_far() -> None:
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        r = pool.submit(_delays_at_double_demand).result()  # libsumo: one simulation per process
    done = np.concatenate(list(r["done"].values()))
    both = np.concatenate(list(r["all"].values()))
    assert len(done) == r["n_arrived"]
    assert r["backlog"] > 0  # twice the demand: the entry is full, vehicles wait to be inserted
    # every vehicle on the road and every waiting one is added, none twice
    assert len(both) == r["n_arrived"] + r["n_active"] + r["backlog"]
    assert both.min() >= -5.0  # a delay so far is never much below zero (speed factor spread)
    assert both.mean() > done.mean()  # the ones still queueing have waited longer than the finishers
    # total time spent counts the vehicles on the road and, on top, the ones waiting to be inserted
    assert r["on_road_vh"] + 0.01 < r["tts_vh"] < r["on_road_vh"] + r["duration_h"] * 1000
