"""V2X merging: the compiled CAM stage (``cam_kernel.CamStage``, issue 27's seventh CPU pass) gives, bit for
bit, what the Python stage it replaced gave (``V2XMerging._communicate`` before it, copied below as the
reference, with ``traffic.v2x.CamGenerator`` for the schedule): the senders, the channel's positions, the
CAM schedule, the listen keys, each CAM's receivers; and it changes nothing when it leaves work to Python."""

from __future__ import annotations

from itertools import accumulate

import numpy as np
import pytest

from corridor.controllers.merging.cam_kernel import (
    STATUS_LISTENERS,
    STATUS_NODES,
    STATUS_OK,
    STATUS_PHASE,
    CamStage,
)
from corridor.controllers.merging.safety_layer import lane_leaders
from corridor.traffic.v2x import CamGenerator

ZONE, MARGIN, RELEASE = 250.0, 100.0, 20.0
BOUNDS = (-RELEASE - 50, ZONE + MARGIN, -RELEASE, ZONE, ZONE, ZONE + 300.0)
PERIOD = 0.1
RSU_NODE = 0


def _case(rng: np.random.Generator, fifo: bool) -> dict:
    """A tick's rows, channel nodes, receivers, schedule and crossing order that need no Python step."""
    n = int(rng.integers(0, 40))
    names = [f"v{j}" for j in rng.permutation(80)[:n].tolist()]
    dist = rng.uniform(-150.0, 600.0, n)
    edge = rng.random(n) < 0.15  # on the masks' edges
    dist[edge] = rng.choice(np.array([ZONE, ZONE + MARGIN, -RELEASE, -RELEASE - 50.0, 0.0, ZONE + 300.0]), size=int(edge.sum()))
    connected = rng.random(n) < 0.8
    pos = rng.uniform(-500.0, 500.0, (n, int(rng.choice([2, 3]))))
    speed = rng.uniform(0.0, 35.0, n)
    ramp, right, merged = rng.random(n) < 0.3, rng.random(n) < 0.4, rng.random(n) < 0.1
    near = connected & (dist < BOUNDS[1]) & (dist > BOUNDS[0])
    in_zone = connected & (dist <= BOUNDS[3]) & (dist > BOUNDS[2])
    # nodes: the RSU, every sender, and some names the rows do not hold; in a shuffled registration order
    extra = [f"x{j}" for j in range(int(rng.integers(0, 6)))]
    named = [names[k] for k in np.flatnonzero(near).tolist()] + extra
    named += [v for v in names if v not in named and rng.random() < 0.3]
    rng.shuffle(named)
    index = {"rsu": RSU_NODE, **{v: j + 1 for j, v in enumerate(named)}}
    receivers = {"rsu"} | {names[k] for k in np.flatnonzero(in_zone).tolist()}
    t = round(float(rng.uniform(0.0, 300.0)), 1)
    next_s = {v: t + PERIOD * float(rng.integers(-3, 4)) + float(rng.choice([0.0, 0.0, 1e-9, -1e-9, 2e-9, 0.03]))
              for v in index if v != "rsu"}
    # the crossing order: rows' vehicles (connected or not) and names without a row
    pool = names + extra + ["h0", "h1"]
    order = [pool[j] for j in rng.permutation(len(pool))[: int(rng.integers(0, min(len(pool), 14) + 1))].tolist()]
    return dict(t=t, names=names, dist=dist, connected=connected, pos=pos, speed=speed, ramp=ramp, right=right,
                merged=merged, index=index, receivers=receivers, next_s=next_s, order=order,
                depth=int(rng.integers(1, 4)), fifo=fifo, r0=int(rng.integers(0, 1000)),
                lane=rng.integers(0, 3, n), lane_pos=np.round(rng.uniform(0.0, 80.0, n), 1))


def _reference(c: dict, known0: np.ndarray, pos0: np.ndarray) -> dict:
    """The Python stage before the kernel (``V2XMerging._communicate``'s lines, on names)."""
    ids, dist, index, order, depth = c["names"], c["dist"], c["index"], c["order"], c["depth"]
    near = c["connected"] & (dist < BOUNDS[1]) & (dist > BOUNDS[0])
    pos = c["pos"]
    idx = np.flatnonzero(near)
    sel = [ids[k] for k in idx.tolist()]
    sel_pos = np.zeros((len(idx) + 1, 3))
    sel_pos[0, :2] = 10.0, -7.5
    sel_pos[1:, : pos.shape[1]] = pos[idx]
    nodes = np.array([RSU_NODE, *[index[v] for v in sel]], dtype=np.int64)
    known, chan_pos = known0.copy(), pos0.copy()
    known[:] = False
    known[nodes] = True
    chan_pos[nodes] = sel_pos
    cams = CamGenerator(1.0 / PERIOD, np.random.default_rng(0))
    cams._next_s = dict(c["next_s"])
    due = idx[cams.due(c["t"], sel)]
    cam_z = np.empty((len(due), 2))
    cam_z[:, 0], cam_z[:, 1] = -dist[due], c["speed"][due]
    cam_pos = np.zeros((len(due), 3))
    cam_pos[:, :2] = pos[due, :2]
    followers: dict[str, list[str]] = {}
    keys: list[int] = []
    newcomers = []
    if c["fifo"]:
        conflict = (c["ramp"] | c["right"]) & ~c["merged"]
        newcomers = [ids[k] for k in idx.tolist() if conflict[k] and ids[k] not in set(order)]
    for pos_, vid in enumerate(order):
        if vid not in c["receivers"]:
            continue
        ahead = order[max(0, pos_ - depth): pos_]
        listen = set(ahead).union(newcomers)
        rx = index[vid] << 32
        keys.extend([rx | index[src] for src in listen if src in index])
        for src in ahead:
            followers.setdefault(src, []).append(vid)
        for src in newcomers:
            if src != vid:
                followers.setdefault(src, []).append(vid)
    keys.sort()
    senders = [ids[k] for k in due.tolist()]
    receivers: list[int] = []
    counts: list[int] = []
    for v in senders:
        receivers.append(RSU_NODE)
        fol = followers.get(v)
        if fol is None:
            counts.append(1)
            continue
        receivers.extend([index.get(f, -1) for f in fol])
        counts.append(1 + len(fol))
    sp = c["speed"][~c["ramp"] & (dist > BOUNDS[4]) & (dist < BOUNDS[5])]
    cand = np.flatnonzero((dist > 0) & (dist <= BOUNDS[3]) & (c["ramp"] | c["right"]) & ~c["merged"])
    return dict(leader=lane_leaders(c["lane"], c["lane_pos"]), cand=cand, stream=(sp.sum(), len(sp)), near=idx, src=[index[v] for v in senders], cam_pos=cam_pos, cam_z=cam_z,
                ptr=[0, *accumulate(counts)], dst=receivers, keys=keys, next_s=cams._next_s, known=known,
                chan_pos=chan_pos)


def _kernel_args(c: dict, rng: np.random.Generator) -> tuple:
    index = c["index"]
    cap = 2 * len(index) + 3
    # nodes past the end of slot_of are no receivers either
    slot_of = np.full(max(index[v] for v in c["receivers"]) + 1 + int(rng.integers(0, 3)), -1, dtype=np.int64)
    for s, v in enumerate(sorted(c["receivers"], key=lambda v: index[v])):
        slot_of[index[v]] = s
    next_s = np.full(cap, np.nan)
    for v, x in c["next_s"].items():
        next_s[index[v]] = x
    known = rng.random(cap) < 0.5
    chan_pos = rng.uniform(-9.0, 9.0, (cap, 3))
    row_node = np.array([index.get(v, -1) for v in c["names"]], dtype=np.int64)
    order_node = np.array([index.get(v, -1) for v in c["order"]], dtype=np.int64)
    return (c["t"], c["dist"], c["connected"], c["pos"], c["speed"], c["ramp"], c["right"], c["merged"], row_node,
            *BOUNDS, slot_of, len(c["receivers"]) - 1, next_s, PERIOD, known, chan_pos, RSU_NODE, 10.0, -7.5,
            order_node, c["depth"], c["fifo"], c["r0"], c["lane"], c["lane_pos"])


@pytest.mark.parametrize("fifo", [False, True])
def test_the_compiled_cam_stage_gives_the_python_stage_bit_for_bit(fifo: bool) -> None:
    rng = np.random.default_rng(27 + fifo)
    cam_stage = CamStage()  # one for all cases: its buffers are reused (and grown)
    total_due = n_followed = 0
    for _ in range(400):
        c = _case(rng, fifo)
        args = _kernel_args(c, rng)
        known, chan_pos, next_s = args[19], args[20], args[17]
        ref = _reference(c, known, chan_pos)
        status, near, src, pos, val, ptr, dst, keys, stream_sum, stream_n, cand, n_due, m, refs, leader = cam_stage(*args)
        assert status == STATUS_OK
        np.testing.assert_array_equal(near, ref["near"])
        assert src[:n_due].tolist() == ref["src"]
        assert pos[:n_due].tobytes() == ref["cam_pos"].tobytes() and val[:n_due].tobytes() == ref["cam_z"].tobytes()
        assert ptr[: n_due + 1].tolist() == ref["ptr"] and dst[:m].tolist() == ref["dst"]
        assert keys.tolist() == ref["keys"]
        # room for the assignments: one per connected coordinated row, from the RSU, references from r0 on
        n_a = int(c["connected"][ref["cand"]].sum())
        assert len(src) == len(pos) == len(val) == len(refs) == len(ptr) - 1 == n_due + n_a and len(dst) >= m + n_a
        assert (src[n_due:] == RSU_NODE).all() and pos[n_due:].tolist() == [[10.0, -7.5, 0.0]] * n_a
        assert not val[n_due:].any() and (refs[:n_due] == -1).all()
        assert refs[n_due:].tolist() == list(range(c["r0"], c["r0"] + n_a))
        assert ptr[n_due:].tolist() == list(range(m, m + n_a + 1))
        np.testing.assert_array_equal(known, ref["known"])
        assert (stream_sum, stream_n) == ref["stream"]
        assert cand.tolist() == ref["cand"].tolist() and leader.tolist() == ref["leader"].tolist()
        assert chan_pos.tobytes() == ref["chan_pos"].tobytes()
        for v, x in ref["next_s"].items():
            assert next_s[c["index"][v]] == x, v  # exact: the period grid's arithmetic
        total_due += n_due
        n_followed += int((np.diff(ptr[: n_due + 1]) > 1).sum())
    assert total_due > 1000 and n_followed > 100  # the cases exercise the schedule and the receivers


def test_the_stage_leaves_names_and_draws_to_python_and_changes_nothing_then() -> None:
    rng = np.random.default_rng(5)
    cam_stage = CamStage()
    seen = set()
    for _ in range(300):
        c = _case(rng, bool(rng.random() < 0.5))
        args = list(_kernel_args(c, rng))
        near = np.flatnonzero(c["connected"] & (c["dist"] < BOUNDS[1]) & (c["dist"] > BOUNDS[0]))
        zone = np.flatnonzero(c["connected"] & (c["dist"] <= BOUNDS[3]) & (c["dist"] > BOUNDS[2]))
        kind = int(rng.integers(0, 4))
        if kind == 0 and len(zone):  # a listener that is not a receiver yet
            args[15] = args[15].copy()
            args[15][c["index"][c["names"][int(rng.choice(zone))]]] = -1
            want = STATUS_LISTENERS
        elif kind == 1:  # a receiver that left the zone
            args[16] += 1
            want = STATUS_LISTENERS
        elif kind == 2 and len(near):  # a sender without a node
            k = int(rng.choice(near))
            args[8] = args[8].copy()
            args[8][k] = -1
            want = STATUS_LISTENERS if k in zone else STATUS_NODES
        elif kind == 3 and len(near):  # a sender without a schedule
            args[17][c["index"][c["names"][int(rng.choice(near))]]] = np.nan
            want = STATUS_PHASE
        else:
            continue
        before = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        out = cam_stage(*args)
        assert out[0] == want
        assert all(len(a) == 0 for a in (*out[1:6], out[7], out[10], out[13], out[14]))
        assert out[8:10] == (0.0, 0) and out[11:13] == (0, 0)
        for a, b in zip(args, before, strict=True):
            if isinstance(a, np.ndarray):
                np.testing.assert_array_equal(a, b)
        seen.add(want)
    assert seen == {STATUS_LISTENERS, STATUS_NODES, STATUS_PHASE}


def test_the_compiled_sum_is_numpys_pairwise_sum() -> None:
    """``pairwise_sum`` (the crossing speed's sum in the CAM stage) is a float64 array's ``sum``, bit for bit,
    below 8, up to 128 and above (halved) values, where a plain running sum differs."""
    from corridor.controllers.merging.cam_kernel import pairwise_sum

    rng = np.random.default_rng(8)
    plain = 0
    for _ in range(5000):
        n = int(rng.integers(0, 600))
        a = rng.uniform(0.0, 35.0, n) * float(rng.choice([1.0, 1e-3, 1e5]))
        lo = int(rng.integers(0, n + 1))
        assert pairwise_sum(a, lo, n - lo) == a[lo:].sum()
        plain += sum(a[lo:].tolist()) != a[lo:].sum()
    assert plain > 1000


def test_the_compiled_lane_leaders_are_the_lexsorts() -> None:
    """``cam_kernel.lane_leaders`` (two stable sorts) gives ``safety_layer.lane_leaders`` (a lexsort), ties in
    position on a lane included (the lower row first)."""
    from corridor.controllers.merging.cam_kernel import lane_leaders as compiled

    rng = np.random.default_rng(12)
    ties = 0
    for _ in range(3000):
        n = int(rng.integers(0, 120))
        lane = rng.integers(0, 4, n)
        pos = np.round(rng.uniform(0.0, 60.0, n), int(rng.integers(0, 2)))
        assert compiled(lane, pos).tolist() == lane_leaders(lane, pos).tolist()
        ties += len(set(zip(lane.tolist(), pos.tolist()))) < n
    assert ties > 1000


def _row_tables(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Random tables behind ``n`` rows: role and connectivity by uid, the rows' uids and lanes, and per
    lane whether it is on the ramp, joins the mainline, or lies past the merge."""
    n_uid, n_lanes = n + int(rng.integers(1, 20)), int(rng.integers(1, 8))
    role = rng.integers(0, 3, n_uid).astype(np.int8)
    uid = rng.permutation(n_uid)[:n].astype(np.int64)
    conn_of = rng.random(n_uid) < 0.8
    lane = rng.integers(0, n_lanes, n)
    on_ramp, joins, past = (rng.random(n_lanes) < 0.4 for _ in range(3))
    return role, uid, conn_of, lane, on_ramp, joins, past


def test_the_compiled_row_facts_are_the_former_sense_lines() -> None:
    """``derive_rows`` (in the same call as the stage, ``CamStage.tick``) gives what ``V2XMerging._sense``'s
    numpy lines gave: the distance to the conflict point (along the ramp on a ramp lane), ramp, merged,
    right and connected; and the stage on them is the stage on the numpy rows."""
    from corridor.controllers.merging.cam_kernel import derive_rows

    rng = np.random.default_rng(21)
    stage, ref_stage = CamStage(), CamStage()
    for _ in range(300):
        c = _case(rng, bool(rng.random() < 0.5))
        n = len(c["names"])
        role, uid, conn_of, lane, on_ramp, joins, past = _row_tables(rng, n)
        front_x = rng.uniform(900.0, 1700.0, n)
        x_merge, cos_ramp = 1521.022, np.cos(np.radians(float(rng.uniform(2.0, 20.0))))
        # the former _sense lines
        ramp = role[uid] == 1
        merged = ramp & past[lane]
        dist = x_merge - front_x
        dist[ramp & on_ramp[lane]] /= cos_ramp
        got = [np.empty(n), *(np.empty(n, dtype=bool) for _ in range(4))]
        derive_rows(front_x, role, uid, conn_of, lane, on_ramp, joins, past, 1, x_merge, cos_ramp, *got)
        assert got[0].tobytes() == dist.tobytes()
        for a, b in zip(got[1:], (conn_of[uid], ramp, joins[lane], merged), strict=True):
            np.testing.assert_array_equal(a, b)
        # the stage on them, in the same call
        c.update(dist=dist, connected=conn_of[uid], ramp=ramp, right=joins[lane], merged=merged, lane=lane)
        args = list(_kernel_args(c, rng))
        args[22] = x_merge  # the conflict point: the RSU's x
        twin = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        want = ref_stage(*args)
        raw = (role, uid, conn_of, on_ramp, joins, past, 1, cos_ramp)
        out = stage.tick(twin[0], front_x, raw, *twin[3:4], twin[4], *twin[8:])
        assert out[0] == want[0]
        for j, (a, b) in enumerate(zip(out[:15], want, strict=True)):
            if j == 6:  # the receivers' buffer: its first m (the CAMs')
                a, b = a[: out[12]], b[: want[12]]
            assert (a.tobytes() == b.tobytes()) if isinstance(a, np.ndarray) else a == b, j
        for j in (17, 19, 20):  # next_s, known, chan_pos advanced alike
            np.testing.assert_array_equal(twin[j], args[j])


def test_the_stage_from_raw_poses_is_the_stage_on_the_snapshots_geometry() -> None:
    """``CamStage.pose_tick`` (issue 27's ninth CPU pass: SUMO's raw poses, the snapshot's geometry not
    derived) gives what ``tick`` gives on the geometry ``corridor.poses.planar_geometry`` derives: the rows'
    front x (``V2XMerging._sense``'s former line), their centres, and with them every output of the stage;
    and ``_sense``'s speed (``np.hypot`` of the raw speed along the yaw) is the snapshot's ``speed``."""
    from corridor.poses import planar_geometry

    rng = np.random.default_rng(29)
    stage, ref_stage = CamStage(), CamStage()
    for _ in range(300):
        c = _case(rng, bool(rng.random() < 0.5))
        n = len(c["names"])
        role, uid, conn_of, lane, on_ramp, joins, past = _row_tables(rng, n)
        # SUMO's columns: the front bumper, the bearing (often due east, else any), the speed, half lengths
        ref_xy = np.column_stack([rng.uniform(900.0, 1700.0, n), rng.uniform(-60.0, 5.0, n)])
        bearing = np.where(rng.random(n) < 0.5, 90.0, rng.uniform(-180.0, 360.0, n))
        speed = rng.uniform(0.0, 35.0, n)
        size = np.column_stack([rng.uniform(3.0, 16.0, n), np.full(n, 1.8), np.full(n, 1.5)])
        back = (0.5 * size[:, 0])[:, None]
        # the snapshot's geometry and the former _sense lines on it
        pos, vel, heading = planar_geometry(ref_xy, bearing, speed, back)
        front_x = pos[:, 0] + 0.5 * size[:, 0] * np.cos(heading)
        yaw = np.radians(90.0 - bearing)
        cos_yaw, sin_yaw = np.cos(yaw), np.sin(yaw)
        assert np.hypot(speed * cos_yaw, speed * sin_yaw).tobytes() == np.hypot(vel[:, 0], vel[:, 1]).tobytes()
        x_merge, cos_ramp = 1521.022, np.cos(np.radians(float(rng.uniform(2.0, 20.0))))
        c.update(pos=pos, lane=lane)
        args = list(_kernel_args(c, rng))
        args[22] = x_merge
        twin = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        raw = (role, uid, conn_of, on_ramp, joins, past, 1, cos_ramp)
        want = ref_stage.tick(args[0], front_x, raw, pos, *args[4:5], *args[8:])
        out = stage.pose_tick(twin[0], (ref_xy, back, cos_yaw, sin_yaw, size), raw, *twin[4:5], *twin[8:])
        assert out[20].tobytes() == np.ascontiguousarray(pos[:, :2]).tobytes()
        assert out[15].tobytes() == want[15].tobytes()  # dist: from the front x
        for j, (a, b) in enumerate(zip(out[:20], want[:20], strict=True)):
            if j == 6:
                a, b = a[: out[12]], b[: want[12]]
            assert (a.tobytes() == b.tobytes()) if isinstance(a, np.ndarray) else a == b, j
        for j in (17, 19, 20):  # next_s, known, chan_pos advanced alike
            assert twin[j].tobytes() == args[j].tobytes(), j
