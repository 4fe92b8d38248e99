"""Continuous collision detection: boxes that pass through each other between two ticks count, boxes
that pass apart do not, teleports and entities that appear or vanish are not swept, and NMAC /
minimum separation see the closest approach between ticks."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from corridor.analysis.ccd import (
    Poses,
    closest_approach,
    interval_below,
    obb_overlap_pairwise,
    swept_overlaps,
)
from corridor.analysis.monitoring.collisions import CollisionMonitor
from corridor.analysis.monitoring.separation import SeparationMonitor
from corridor.engine import Backend, RunContext, Simulation
from corridor.snapshot import Kind, Role, WorldSnapshot

QUAD = (0.45, 0.45, 0.2)  # [m] length, width, height of a small quadcopter
DT = 0.1  # [s]


class Scripted(Backend):
    """Plays back one (ids, positions[N, 3], headings[N]) frame per tick."""

    def __init__(self, frames: list[tuple[list[str], np.ndarray, np.ndarray]], size=QUAD, kind=Kind.UAV) -> None:
        super().__init__("air")
        self.period = DT
        self.frames, self.size, self.kind, self.k = frames, size, kind, 0

    def tick(self, ctx: RunContext) -> None:
        self.k += 1

    def snapshot_part(self) -> WorldSnapshot:
        ids, pos, yaw = self.frames[min(self.k, len(self.frames)) - 1]
        n = len(ids)
        return WorldSnapshot(ids=np.array(ids, dtype=object), kind=np.full(n, self.kind, dtype=np.int8),
                             role=np.full(n, Role.OTHER, dtype=np.int8), position=np.asarray(pos, float).copy(),
                             velocity=np.zeros((n, 3)), heading=np.asarray(yaw, float).copy(),
                             size=np.tile(self.size, (n, 1)))


def run(frames, monitor="collisions", **params) -> tuple[dict, RunContext]:
    scen = SimpleNamespace(dt=DT)
    if monitor == "collisions":
        mon = CollisionMonitor("collisions", CollisionMonitor.Params(), scen)
    else:
        mon = SeparationMonitor("sep", SeparationMonitor.Params(backend=None, **params), scen)
    ctx = RunContext(run_seed=0, dt=DT, duration=DT * len(frames))
    return Simulation(ctx, [Scripted(frames), mon]).run(), ctx


def head_on(x0: float, lateral_m: float = 0.0, closing_each_mps: float = 12.0, ticks: int = 2):
    """Two quadcopters on the x axis flying at each other; a at -x0, b at +x0 at the first tick."""
    step = closing_each_mps * DT
    return [(["a", "b"], np.array([[-x0 + k * step, 0.0, 50.0], [x0 - k * step, lateral_m, 50.0]]),
             np.array([0.0, np.pi])) for k in range(ticks)]


def test_closest_approach_closed_form() -> None:
    s, d = closest_approach(np.array([[10.0, 3.0, 0.0], [4.0, 0.0, 0.0], [5.0, 0.0, 0.0], [1.0, 2.0, 2.0]]),
                            np.array([[-10.0, 3.0, 0.0], [0.0, 4.0, 0.0], [3.0, 0.0, 0.0], [1.0, 2.0, 2.0]]))
    assert s == pytest.approx([0.5, 0.5, 1.0, 0.0])
    assert d == pytest.approx([3.0, 2.0 * np.sqrt(2.0), 3.0, 3.0])
    # horizontal passage at 24 m/s closing with a 0.3 m lateral offset, between ticks
    s, d = closest_approach(np.array([[-1.2, -0.3]]), np.array([[1.2, -0.3]]))
    assert s[0] == pytest.approx(0.5) and d[0] == pytest.approx(0.3)


def test_interval_below_exact_roots() -> None:
    # |(-5 + 10 s, 3)| < 5  <=>  (10 s - 5)^2 < 16  <=>  s in (0.1, 0.9)
    lo, hi = interval_below(np.array([[-5.0, 3.0]]), np.array([[5.0, 3.0]]), 5.0)
    assert lo[0] == pytest.approx(0.1) and hi[0] == pytest.approx(0.9)
    lo, hi = interval_below(np.array([[-5.0, 6.0]]), np.array([[5.0, 6.0]]), 5.0)
    assert lo[0] > hi[0]  # never inside
    lo, hi = interval_below(np.array([[1.0], [9.0]]), np.array([[1.0], [9.0]]), np.array([2.0, 2.0]))
    assert (lo[0], hi[0]) == (0.0, 1.0) and lo[1] > hi[1]  # no relative motion: all or nothing


def test_pass_through_between_ticks_is_one_collision() -> None:
    frames = head_on(0.6)  # +-0.6 m at the first tick, -+0.6 m at the next: never overlapping at a tick
    d = frames[0][1][1] - frames[0][1][0]
    assert abs(d[0]) > QUAD[0] and abs(frames[1][1][1][0] - frames[1][1][0][0]) > QUAD[0]
    m, ctx = run(frames)
    assert m["collisions"] == 1
    assert m["first_collision_s"] == pytest.approx(DT + 0.5 * DT)  # the centres meet half-way
    (ev,) = ctx.events.of_kind("collision")
    assert "between ticks" in ev.message


def test_pass_two_metres_apart_is_no_collision() -> None:
    m, _ = run(head_on(0.6, lateral_m=2.0))
    assert m["collisions"] == 0


def test_overlap_at_a_tick_keeps_the_tick_time() -> None:
    frames = [(["a", "b"], np.array([[-1.0, 0.0, 50.0], [1.0, 0.0, 50.0]]), np.zeros(2)),
              (["a", "b"], np.array([[-0.1, 0.0, 50.0], [0.1, 0.0, 50.0]]), np.zeros(2))]
    m, _ = run(frames)
    assert m["collisions"] == 1 and m["first_collision_s"] == pytest.approx(2 * DT)


def test_vertical_separation_between_ticks_is_respected() -> None:
    frames = head_on(0.6)
    frames = [(ids, pos + np.array([[0, 0, 0], [0, 0, 0.25]]), yaw) for ids, pos, yaw in frames]  # > 0.2 m
    m, _ = run(frames)
    assert m["collisions"] == 0


def test_teleport_and_appearing_entities_are_not_swept() -> None:
    # b jumps 400 m through a's position in one tick: a teleport, not motion
    frames = [(["a", "b"], np.array([[0.0, 0.0, 50.0], [-200.0, 0.0, 50.0]]), np.zeros(2)),
              (["a", "b"], np.array([[0.0, 0.0, 50.0], [200.0, 0.0, 50.0]]), np.zeros(2))]
    assert run(frames)[0]["collisions"] == 0
    # c appears on the far side of a; b vanishes (the rows shift: matching is by id, not by row)
    frames = [(["a", "b"], np.array([[0.0, 0.0, 50.0], [-1.0, 0.0, 50.0]]), np.zeros(2)),
              (["c", "a"], np.array([[1.0, 0.0, 50.0], [0.0, 5.0, 50.0]]), np.zeros(2))]
    prev = Poses(0.0, np.array(frames[0][0], dtype=object), frames[0][1], frames[0][2], np.tile(QUAD, (2, 1)))
    cur = Poses(0.1, np.array(frames[1][0], dtype=object), frames[1][1], frames[1][2], np.tile(QUAD, (2, 1)))
    i, j, _ = swept_overlaps(prev, cur)
    assert len(i) == 0  # a (moving from (0,0) to (0,5)) meets nobody; c did not exist before


def test_obb_pairwise_rotated() -> None:
    size = np.array([[4.0, 1.0, 1.0]])
    z = np.zeros((1, 3))
    # a long thin box along x and one along y crossing it: overlap; shifted 2.6 m in y: apart
    assert obb_overlap_pairwise(z, np.array([0.0]), size, z, np.array([np.pi / 2]), size)[0]
    far = np.array([[0.0, 2.6, 0.0]])
    assert not obb_overlap_pairwise(z, np.array([0.0]), size, far, np.array([np.pi / 2]), size)[0]
    # diagonal box: overlap only in the bounding circles, not the boxes
    d = np.array([[2.3, 1.2, 0.0]])
    assert not obb_overlap_pairwise(z, np.array([0.0]), size, d, np.array([0.0]), size)[0]


def test_nmac_and_min_separation_between_ticks() -> None:
    # 20 m lateral offset; in one interval the relative x goes from -80 m to +80 m, so both ticks are
    # outside the 30.48 m NMAC and 60.96 m LoS cylinders (80 m per tick is below the teleport limit)
    frames = [(["a", "b"], np.array([[-40.0 + 80.0 * k, 0.0, 50.0], [40.0 - 80.0 * k, 20.0, 50.0]]),
               np.array([0.0, np.pi])) for k in range(2)]
    m, ctx = run(frames, monitor="sep")
    assert m["sep_min_h_m"] == pytest.approx(20.0)
    assert m["sep_min_3d_m"] == pytest.approx(20.0)
    assert m["sep_min_v_m"] == pytest.approx(0.0)
    assert m["nmac"] == 1 and m["los"] == 1
    (ev,) = ctx.events.of_kind("nmac")
    assert ev.data["h_m"] == pytest.approx(20.0)
    # the same pass 40 m apart: LoS (60.96 m) but no NMAC (30.48 m)
    frames = [(ids, pos + np.array([[0, 0, 0], [0, 20.0, 0]]), yaw) for ids, pos, yaw in frames]
    m, _ = run(frames, monitor="sep")
    assert m["nmac"] == 0 and m["los"] == 1 and m["sep_min_h_m"] == pytest.approx(40.0)


def test_nmac_needs_horizontal_and_vertical_at_the_same_time() -> None:
    # horizontally inside only early in the interval, vertically inside only late: no NMAC
    frames = [(["a", "b"], np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 20.0]]), np.zeros(2)),
              (["a", "b"], np.array([[0.0, 0.0, 0.0], [80.0, 0.0, 0.0]]), np.zeros(2))]
    m, _ = run(frames, monitor="sep")  # at the first tick 20 m vertical (> 4.572) and 0 horizontal
    assert m["nmac"] == 0


def test_the_collision_monitors_skip_never_hides_a_contact() -> None:
    """``_may_touch`` (the collision monitor's cheap necessary condition) is True whenever the box checks
    find a pair: 4000 random scenes of boxes moving up to 40 m per tick, many of them in contact."""
    from corridor.analysis.monitoring.collisions import _may_touch
    from corridor.analysis.safety import obb_overlap_pairs

    rng = np.random.default_rng(7)
    found = skipped = 0
    for _ in range(4000):
        n = int(rng.integers(2, 7))
        ids = np.array([f"v{k}" for k in range(n)], dtype=object)
        size = np.column_stack([rng.uniform(0.3, 12, n), rng.uniform(0.3, 3, n), rng.uniform(0.2, 4, n)])
        p0 = rng.uniform(-15, 15, (n, 3)) * [1, 1, 0.2]
        p1 = p0 + rng.uniform(-40, 40, (n, 3)) * rng.uniform(0, 1) * [1, 1, 0.1]
        prev = Poses(0.0, ids, p0, rng.uniform(-np.pi, np.pi, n), size)
        cur = Poses(0.1, ids, p1, rng.uniform(-np.pi, np.pi, n), size)
        rows = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
        hits = len(obb_overlap_pairs(p1[:, :2], cur.heading, size[:, 0], size[:, 1], p1[:, 2], size[:, 2],
                                     involving=rows)) + len(swept_overlaps(prev, cur, rows)[0])
        found += hits > 0
        may = _may_touch(prev, cur, rows)
        skipped += not may
        assert may or hits == 0
    assert found > 500 and skipped > 100  # the scenes exercise contacts, and scenes the check skips
