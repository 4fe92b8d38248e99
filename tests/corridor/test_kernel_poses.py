"""Lazily derived snapshot geometry (``corridor.poses``): closed forms, derived only when read, and
the same bits whichever path derives it (one tick alone, a block of ticks, joined parts)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.poses import PlanarPoses, planar_geometry
from corridor.snapshot import WorldSnapshot, fill_geometry


def _poses(rng: np.random.Generator, n: int) -> PlanarPoses:
    return PlanarPoses(rng.uniform(-500, 500, (n, 2)), rng.uniform(0, 360, n), rng.uniform(0, 40, n),
                       rng.choice([2.4, 6.0], (n, 1)))


def _lazy(poses: PlanarPoses) -> WorldSnapshot:
    n = len(poses)
    return WorldSnapshot(ids=np.array([f"v{k}" for k in range(n)], dtype=object), kind=np.zeros(n, np.int8),
                         role=np.zeros(n, np.int8), size=np.ones((n, 3)), poses=poses)


def test_front_bumper_bearing_and_speed_give_centre_velocity_and_yaw() -> None:
    # heading east (bearing 90 deg) and north (0 deg), 20 m/s, front bumper 2.4 m ahead of the centre
    pos, vel, yaw = planar_geometry(np.array([[10.0, 0.0], [0.0, 10.0]]), np.array([90.0, 0.0]),
                                    np.array([20.0, 20.0]), np.array([[2.4], [2.4]]))
    assert yaw[0] == 0.0 and yaw[1] == pytest.approx(math.pi / 2)
    assert pos[0].tolist() == [7.6, 0.0, 0.0] and pos[1] == pytest.approx([0.0, 7.6, 0.0], abs=1e-12)
    assert vel[0].tolist() == [20.0, 0.0, 0.0] and vel[1] == pytest.approx([0.0, 20.0, 0.0], abs=1e-12)
    assert not (pos.flags.writeable or vel.flags.writeable or yaw.flags.writeable)


def test_geometry_is_derived_on_first_read_only_and_cached() -> None:
    p = _poses(np.random.default_rng(0), 7)
    s = _lazy(p)
    assert len(s) == 7 and s.pending_poses() == [p] and not p.filled  # ids/sizes read: nothing derived
    pos = s.position
    assert p.filled and s.pending_poses() == [] and s.position is pos
    ref = planar_geometry(p.ref_xy, p.bearing_deg, p.speed_mps, p.back_m)
    for got, want in zip((s.position, s.velocity, s.heading), ref, strict=True):
        assert np.array_equal(got, want)
    with pytest.raises(ValueError, match="read-only"):
        s.position[0, 0] = 1.0
    with pytest.raises(ValueError, match="not both"):
        WorldSnapshot(position=np.zeros((0, 3)), poses=p)


def test_a_block_derives_the_same_bits_as_each_tick_alone() -> None:
    sizes = [0, 1, 3, 250, 17, 301, 2]
    alone = [_lazy(_poses(np.random.default_rng(k), n)) for k, n in enumerate(sizes)]
    block = [_lazy(_poses(np.random.default_rng(k), n)) for k, n in enumerate(sizes)]
    block[3].velocity  # noqa: B018  (one already derived on its own: kept)
    fill_geometry(block)
    assert all(not s.pending_poses() for s in block)
    for a, b in zip(alone, block, strict=True):
        for f in ("position", "velocity", "heading"):
            assert np.array_equal(getattr(a, f), getattr(b, f))  # bit for bit (== on floats)
            assert not getattr(b, f).flags.writeable


def test_joined_parts_stay_lazy_and_match_the_eager_join() -> None:
    rng = np.random.default_rng(2)
    road = _lazy(_poses(rng, 5))
    air = WorldSnapshot(ids=np.array(["u0", "u1"], dtype=object), kind=np.full(2, 2, np.int8),
                        role=np.zeros(2, np.int8), position=rng.normal(size=(2, 3)), velocity=rng.normal(size=(2, 3)),
                        heading=rng.normal(size=2), size=np.ones((2, 3)))
    joined = WorldSnapshot.from_parts(1.0, [air, road])
    assert joined.pending_poses() and road.pending_poses()  # nothing derived by joining
    fill_geometry([joined])  # derives the road part's poses
    assert not road.pending_poses()
    for f in ("position", "velocity", "heading"):
        assert np.array_equal(getattr(joined, f), np.concatenate([getattr(air, f), getattr(road, f)]))
    eager = WorldSnapshot.from_parts(1.0, [air, road])  # both derived now: joined eagerly
    assert not eager.pending_poses() and np.array_equal(eager.position, joined.position)
