"""The multi-fidelity fleet's 6-DOF aircraft split into shard processes (``params.shards``): the rows
equal the one-process run's (the FDM pools are per group, and a group lives in one shard), the shard
processes end with the run, and a shard count outside 1..POOL_GROUPS is refused."""

from __future__ import annotations

import math
from typing import Any

import pytest

from corridor.errors import CorridorError
from corridor.run import simulate
from corridor.scenario import load
from corridor.vehicles.air.jsbsim_switch import POOL_GROUPS
from tests.conftest import scenario_file

CITY = scenario_file("uav_city")
SMALL = ["backends.air.params.city.n=80", "backends.air.params.city.size_m=1200", "backends.air.params.city.vertiports=6",
         "backends.air.params.city.vertiport_spacing_m=200", "backends.air.params.city.start_spacing_m=60",
         "duration=20"]
MACHINE = {"wall_s", "rtf", "cpu_per_sim_s"}  # measurements of the machine, not of the scenario


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def test_two_shards_give_the_one_shard_rows() -> None:
    rows = {}
    for k in (1, 2):
        sc, _ = load(CITY, [*SMALL, f"backends.air.params.shards={k}"])
        rows[k] = simulate(sc, 0)[0]
    one, two = rows[1], rows[2]
    assert one["promotions"] >= 20 and one["demotions"] >= 1  # the shards' fleets change during the run
    differ = {k: (one[k], two[k]) for k in sorted(set(one) - MACHINE) if not _same(one[k], two[k])}
    assert differ == {}
    assert set(one) == set(two)
    assert two["cpu_per_sim_s"] > 0.0  # the shard processes' CPU is counted


def test_shard_count_is_checked() -> None:
    with pytest.raises(CorridorError, match="shards"):
        load(CITY, [*SMALL, f"backends.air.params.shards={POOL_GROUPS + 1}"])


def test_exchange_is_timed_per_round_trip() -> None:
    """The diagnostics ``benchmarks/uav_city.py --shards`` prints: one round trip per step (plus one at
    start-up), their wall time, and the slowest shard's work inside it."""
    from corridor.vehicles.air.jsbsim_shards import ShardedJSBSimFleet

    fleet = ShardedJSBSimFleet((47.3769, 8.5417, 408.0), 2)
    try:
        fleet.spawn_in_flight("a", (0.0, 0.0, 60.0), (7.0, 0.0, 0.0), 0.0, 0.0, 0.0, group=0)
        fleet.spawn_in_flight("b", (500.0, 0.0, 60.0), (-7.0, 0.0, 0.0), 3.14159, 0.0, 0.0, group=1)
        for _ in range(5):
            fleet.step(0.1)
        assert fleet.rounds == 6
        assert 0.0 < fleet.slowest_work_s < fleet.round_wall_s
        assert sorted(fleet.ids) == ["a", "b"]
    finally:
        fleet.close()
