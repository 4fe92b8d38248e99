"""The 6-DOF fleet's per-aircraft bookkeeping (O(1) per aircraft since the 10,000-drone profile):
targets that grow and delete in place, id -> row lookups that follow removals, the fleet velocity
command equal to one command per aircraft, and FDM pools per group."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.air.autopilot import QuadMode, QuadTargets, VelocityCommand
from corridor.vehicles.air.jsbsim_switch import SwitchableJSBSimFleet

ORIGIN = (47.3769, 8.5417, 408.0)


def test_quad_targets_append_and_delete_like_arrays() -> None:
    rng = np.random.default_rng(0)
    tgt, ref_p, ref_y = QuadTargets(), [], []
    for k in range(21):  # past two doublings of the buffers
        p = rng.normal(0.0, 100.0, 3)
        tgt.append(p, 0.1 * k, 5.0)
        ref_p.append(p)
        ref_y.append(0.1 * k)
    tgt.v_enu[3] = [1.0, 2.0, 3.0]
    tgt.mode[3] = QuadMode.VELOCITY
    for q in (0, 7, 18):
        tgt.delete(q)
        del ref_p[q], ref_y[q]
    assert len(tgt) == 18 and tgt.p_enu.shape == (18, 3)
    np.testing.assert_array_equal(tgt.p_enu, np.array(ref_p))
    np.testing.assert_array_equal(tgt.yaw_rad, np.array(ref_y))
    assert tgt.mode[2] == QuadMode.VELOCITY and list(tgt.v_enu[2]) == [1.0, 2.0, 3.0]  # row 3 moved up
    assert np.all(tgt.speed_limit_mps == 5.0)
    with pytest.raises(IndexError):
        tgt.delete(18)


def _fleet(n: int) -> SwitchableJSBSimFleet:
    f = SwitchableJSBSimFleet(ORIGIN, 120.0)
    for k in range(n):
        f.spawn_in_flight(f"q{k}", np.array([40.0 * k, 0.0, 60.0]), np.array([3.0, 0.0, 0.0]), 0.0, 0.0, 0.0,
                          group=k % 2)
    return f


def test_rows_follow_removals_and_fleet_command_equals_single_commands() -> None:
    a, b = _fleet(5), _fleet(5)
    for f in (a, b):
        f.step(0.5)
        f.remove("q1")
        f.remove("q3")
        assert f.ids == ["q0", "q2", "q4"]
        assert [f._row(i) for i in f.ids] == [0, 1, 2] and f._quad_rows == [0, 1, 2]
        with pytest.raises(ValueError, match="q1"):
            f.command("q1", VelocityCommand((1.0, 0.0, 0.0)))
    v = np.array([[2.0, 1.0, 0.0], [-1.0, 3.0, 0.5], [0.0, 0.0, -1.0]])
    a.command_velocities(["q4", "q0", "q2"], v[[2, 0, 1]])
    for i, row in zip(["q0", "q2", "q4"], v, strict=True):
        b.command(i, VelocityCommand(tuple(map(float, row))))
    for name in QuadTargets._FIELDS:
        np.testing.assert_array_equal(getattr(a.quad_targets, name), getattr(b.quad_targets, name))
    a.step(1.0)
    b.step(1.0)
    np.testing.assert_array_equal(a.state().position, b.state().position)
    assert np.linalg.norm(a.state().velocity[0, :2] - v[0, :2]) < 1.0  # q0 follows its command


def test_removed_fdms_go_back_to_their_groups_pool() -> None:
    f = _fleet(4)
    fdm_q1 = f._fdms[1]
    f.remove("q1")  # group 1
    assert f._pools[1][-1] is fdm_q1
    f.spawn_in_flight("q9", np.array([0.0, 300.0, 60.0]), np.zeros(3), 0.0, 0.0, 0.0, group=0)
    assert f._fdms[-1] is not fdm_q1  # group 0 takes from its own pool
    f.spawn_in_flight("q8", np.array([0.0, 400.0, 60.0]), np.zeros(3), 0.0, 0.0, 0.0, group=1)
    assert f._fdms[-1] is fdm_q1


def test_pool_growth_and_spawns_are_timed_apart() -> None:
    """The cost curve's diagnostics: a spawn that grows the pool charges the growth (model loads,
    spin-up) to ``warm_cpu_s``, not to ``spawn_cpu_s``; a spawn from a full pool only to the latter."""
    f = _fleet(1)  # group 0's pool grown once: WARM_BATCH FDMs
    warm, spawn = f.warm_cpu_s, f.spawn_cpu_s
    assert warm > 0.0 and spawn > 0.0
    assert warm > 5.0 * spawn  # loads and a 1 s hover of 8 FDMs against one initial-condition run
    f.spawn_in_flight("q1", np.array([0.0, 300.0, 60.0]), np.zeros(3), 0.0, 0.0, 0.0, group=0)
    assert f.warm_cpu_s == warm and f.spawn_cpu_s > spawn


def test_a_prefetched_batch_flies_as_one_warmed_at_the_spawn() -> None:
    """A sharded rank warms FDM batches while it waits for its peers (``prefetch``, one chunk per
    call); a pool that grows takes the reserve's batch instead of warming one then: the same
    trajectories, the same model loads, and no loading at the spawn."""
    ref = _fleet(0)
    pre = _fleet(0)
    chunks = 0
    while pre.prefetch():
        chunks += 1
    assert chunks >= 8 and len(pre._reserve) == 1  # a batch in reserve, a model load per chunk
    assert pre.loads == 0  # loads count when a pool takes the batch
    for f in (ref, pre):
        for k in range(3):  # groups 0 and 1: two pools grow, the first from the reserve
            f.spawn_in_flight(f"q{k}", np.array([40.0 * k, 0.0, 60.0]), np.array([3.0, 0.0, 0.0]), 0.0, 0.02, -0.03,
                              group=k % 2)
        f.step(2.0)
    assert pre.prefetched == 1 and ref.prefetched == 0
    assert pre.loads == ref.loads == 16
    np.testing.assert_array_equal(pre.state().position, ref.state().position)
    np.testing.assert_array_equal(pre.state().velocity, ref.state().velocity)
    assert pre.warm_cpu_s < 0.8 * ref.warm_cpu_s  # one of the two growths took the warmed batch: no loads then
    assert pre.prefetch()  # the reserve is empty: a new batch starts
