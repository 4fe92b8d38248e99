"""corridor.shards: collectives between spawned ranks, a failing rank, strips, the merged event log."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import pytest

from corridor.events import Event
from corridor.shards import ShardComm, Strips, balanced_edges, merge_events, run_sharded


def _rank(fail_on: int, comm: ShardComm) -> tuple[dict[str, Any], list[Event]]:
    """Every collective once; rank ``fail_on`` raises after the first."""
    got = comm.allgather(("rank", comm.rank))
    if comm.rank == fail_on:
        raise ValueError(f"rank {comm.rank} cannot go on")
    total = comm.sum(comm.rank + 1.0)
    low = comm.min_array(np.array([10.0 - comm.rank, float(comm.rank)]))
    events = [Event(1.0, "mon", "los", f"pair of rank {comm.rank}", {}), Event(0.5, "air", "promote", "same", {})]
    return {"got": got, "total": total, "low": low.tolist()}, events


def test_collectives_over_three_ranks() -> None:
    metrics, events, comm = run_sharded(partial(_rank, -1), partial(_rank, -1), 3)
    assert metrics == {"got": [("rank", 0), ("rank", 1), ("rank", 2)], "total": 6.0, "low": [8.0, 0.0]}
    # the replicated event once, each rank's own one, in time order
    assert [e.message for e in events] == ["same", "pair of rank 0", "pair of rank 1", "pair of rank 2"]
    assert comm.rounds == 3


def test_a_failing_rank_fails_the_run_with_its_message() -> None:
    with pytest.raises(RuntimeError, match="shard 1 failed: ValueError: rank 1 cannot go on"):
        run_sharded(partial(_rank, 1), partial(_rank, 1), 2)


def test_shard_count_bounds() -> None:
    with pytest.raises(ValueError, match="shards must be between 2 and 8"):
        run_sharded(partial(_rank, -1), partial(_rank, -1), 9)


def test_strips_split_at_the_quantiles() -> None:
    x = np.array([-3.0, -1.0, 1.0, 3.0])
    s = Strips(x, 2)
    assert s.edges.tolist() == [0.0]
    assert s.owner(np.array([-0.1, 0.0, 0.1])).tolist() == [0, 1, 1]
    assert s.within(x, 0).tolist() == [True, True, False, False]
    assert s.within(x, 1, halo_m=1.5).tolist() == [False, True, True, True]


def test_merge_events_keeps_rank_zeros_order_within_an_instant() -> None:
    a = [Event(1.0, "x", "k", "a1", {}), Event(1.0, "x", "k", "a2", {})]
    b = [Event(0.5, "y", "k", "b", {}), Event(1.0, "x", "k", "a2", {})]
    assert [e.message for e in merge_events([a, b])] == ["b", "a1", "a2"]


def _late_peer(comm: ShardComm) -> tuple[dict[str, Any], list[Event]]:
    """Rank 1 is late to the first collective, rank 0 to the second; rank 0 counts its idle calls."""
    import time

    calls: list[int] = []

    def idle() -> bool:
        calls.append(1)
        time.sleep(0.001)  # a chunk of work
        return len(calls) < 50  # then nothing left

    comm.idle = idle
    # the lower rank's receive waits for its peer's answer (a round trip): with the default 2 ms a loaded
    # machine's scheduling alone started a chunk (CI); 0.1 s is no round trip and still far below 0.3 s
    comm.idle_after_s = 0.1
    if comm.rank == 1:
        time.sleep(0.3)
    first = comm.allgather(comm.rank)
    while_waiting = len(calls)
    if comm.rank == 0:
        time.sleep(0.3)
    second = comm.allgather(comm.rank)
    return {"first": first, "second": second, "while_waiting": while_waiting,
            "when_not": len(calls) - while_waiting, "idle_s": comm.idle_s}, []


def test_a_waiting_rank_does_idle_work_only_while_its_peer_is_late() -> None:
    metrics, _, _ = run_sharded(_late_peer, _late_peer, 2)
    assert metrics["first"] == metrics["second"] == [0, 1]  # the idle work does not touch the messages
    assert 10 <= metrics["while_waiting"] <= 50  # chunks while rank 1 was late (until nothing was left)
    assert metrics["when_not"] == 0  # rank 1's message was there: no idle work
    assert metrics["idle_s"] >= 0.0


def test_balanced_edges_even_out_the_work() -> None:
    x = np.arange(100.0)  # [m] a point per metre, one unit of work each
    assert balanced_edges(x, np.zeros(2), 2).tolist() == [49.5]  # as many points each
    # rank 0 has 40 units besides: it gets 30 points, rank 1 70 (70 units each)
    assert balanced_edges(x, np.array([40.0, 0.0]), 2).tolist() == [29.5]
    # more fixed work than points: rank 0 gets none but the one a strip keeps
    assert balanced_edges(x, np.array([500.0, 0.0]), 2).tolist() == [0.5]
    e = balanced_edges(x, np.array([0.0, 30.0, 0.0]), 3)  # the middle rank's strip narrows
    assert e is not None and np.diff(np.concatenate([[-0.5], e, [99.5]])).tolist() == [43.0, 14.0, 43.0]


def test_strips_follow_the_load_by_bounded_steps() -> None:
    x = np.arange(100.0)
    s = Strips(x, 2)
    assert s.edges.tolist() == [49.5]
    path = []
    for _ in range(4):
        s.rebalance(x, np.array([40.0, 0.0]), max_step_m=8.0)
        path.append(float(s.edges[0]))
    assert path == [41.5, 33.5, 29.5, 29.5]  # toward the balanced edge, 8 m at a time, then stays
    again = Strips(x, 2)
    for _ in range(4):
        again.rebalance(x, np.array([40.0, 0.0]), max_step_m=8.0)
    assert again.edges.tolist() == s.edges.tolist()  # the same inputs, the same edges (every rank)
    s.rebalance(x, np.array([0.0, 40.0]), max_step_m=100.0)
    assert s.edges.tolist() == [69.5]  # the load moved to rank 1: its strip shrinks


def _posting(comm: ShardComm) -> tuple[dict[str, Any], list[Event]]:
    comm.post(np.full(2, float(comm.rank)))
    got = comm.allgather(("tick", comm.rank))
    carried = [c[0].tolist() for c in comm.carried]
    comm.allgather(None)
    return {"got": got, "carried": carried, "after": comm.carried}, []


def test_posted_objects_travel_with_the_next_collective() -> None:
    metrics, _, comm = run_sharded(_posting, _posting, 3)
    assert metrics["got"] == [("tick", 0), ("tick", 1), ("tick", 2)]  # the collective's own values
    assert metrics["carried"] == [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]  # every rank's post, in rank order
    assert metrics["after"] == [[], [], []]  # posted once: the next collective carries nothing
    assert comm.rounds == 2
