"""MAVLink 2 link: pymavlink decodes our bytes exactly; corruption is counted, never fatal."""

from __future__ import annotations

import socket

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from corridor.channel import BernoulliLoss, Channel, ChannelConfig
from corridor.vehicles.geodesy import Origin
from corridor.vehicles.mavlink.decode import (
    MavlinkDecoder,
    report_from_messages,
)
from corridor.vehicles.mavlink.encode import (
    GCS_SYSID,
    MavlinkEndpoint,
)
from corridor.vehicles.mavlink.link import (
    LinkRates,
    MavlinkLink,
    parse_udp_address,
)

ORIGIN = Origin(47.3769, 8.5417, 408.0)
P = np.array([123.456, -78.912, 34.567])  # [m] ENU
V = np.array([3.21, -1.23, 0.45])  # [m/s] ENU


def _frames() -> tuple[MavlinkEndpoint, list[bytes]]:
    ep = MavlinkEndpoint(7, ORIGIN)
    return ep, [ep.heartbeat(), ep.global_position_int(12.345, P, V, 0.3), ep.local_position_ned(12.345, P, V)]


def test_frames_are_mavlink2_and_decode_with_pymavlink_parser() -> None:
    _, frames = _frames()
    assert all(f[0] == 0xFD for f in frames)  # MAVLink 2 magic
    parser = mavlink2.MAVLink(None)
    msgs = parser.parse_buffer(b"".join(frames))
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"]
    assert [m.get_seq() for m in msgs] == [0, 1, 2] and {m.get_srcSystem() for m in msgs} == {7}
    assert msgs[0].type == mavlink2.MAV_TYPE_QUADROTOR
    g, loc = msgs[1], msgs[2]
    lat, lon, h = ORIGIN.to_geodetic(P)
    assert abs(g.lat * 1e-7 - lat) <= 0.5e-7 and abs(g.lon * 1e-7 - lon) <= 0.5e-7  # within 1e-7 deg
    assert g.alt == round(float(h) * 1e3) and g.relative_alt == round(P[2] * 1e3)
    assert (g.vx, g.vy, g.vz) == (-123, 321, -45)  # NED cm/s
    assert g.time_boot_ms == 12345 and loc.time_boot_ms == 12345
    enu_back = np.array([loc.y, loc.x, -loc.z])
    assert np.abs(enu_back - P).max() < 0.01  # local round trip within 1 cm
    assert np.allclose([loc.vy, loc.vx, -loc.vz], V, atol=1e-5)
    # the geodetic report converts back to the same ENU point within 1 cm horizontally (1e-7 deg ~ 1.1 cm)
    back = ORIGIN.to_enu(g.lat * 1e-7, g.lon * 1e-7, g.alt * 1e-3)
    assert np.abs(back - P).max() < 0.011


def test_byte_log_decodes_with_mavutil(tmp_path) -> None:
    path = tmp_path / "link.mav"
    ch = Channel(ChannelConfig(latency_s=0.0, jitter_s=0.0), np.random.default_rng(0))
    link = MavlinkLink(ch, ORIGIN, log_path=str(path))
    link.add_uav("u1")
    link.add_piloted("c172", icao=0xABCDEF, callsign="N172X")
    for k in range(20):
        t = 0.1 * k
        link.publish(t, ["u1", "c172"], np.array([P, P + 500.0]), np.array([V, [50.0, 0, 0]]), np.zeros(2))
    link.command(2.0, "u1", p_enu=P, yaw_rad=0.5)
    link.close()
    conn = mavutil.mavlink_connection(str(path), notimestamps=True, dialect="common")
    counts: dict[str, int] = {}
    while (m := conn.recv_match(blocking=False)) is not None:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
        if m.get_type() == "ADSB_VEHICLE":
            assert m.ICAO_address == 0xABCDEF and m.callsign == "N172X"
            assert m.hor_velocity == 5000 and m.heading == 9000  # 50 m/s towards east
    # 2 s: UAV + GCS heartbeats at 1 Hz, UAV position messages and ADS-B at 10 Hz
    assert counts == {
        "HEARTBEAT": 4, "GLOBAL_POSITION_INT": 20, "LOCAL_POSITION_NED": 20, "ADSB_VEHICLE": 20,
        "SET_POSITION_TARGET_LOCAL_NED": 1,
    }


def test_garbage_and_bit_flips_are_counted_and_later_frames_survive() -> None:
    ep, frames = _frames()
    good = [ep.local_position_ned(0.1 * k, P + k, V) for k in range(5)]
    flipped = bytearray(frames[1])
    flipped[15] ^= 0x04  # payload bit flip -> CRC mismatch
    garbage = bytes(np.random.default_rng(3).integers(0, 256, 40, dtype=np.uint8))
    stream = good[0] + garbage + good[1] + bytes(flipped) + good[2] + b"\xfd\xff\x00" + good[3] + good[4]
    dec = MavlinkDecoder()
    msgs = dec.decode_datagram(stream)
    assert [round(m.y - P[0]) for m in msgs] == [0, 1, 2, 3, 4]  # every valid frame, in order
    assert dec.counters.messages == 5
    assert dec.counters.bad_crc >= 1
    assert dec.counters.bad_data >= 2  # the garbage run and the fake 3-byte header
    assert dec.counters.bytes_dropped >= len(garbage) + len(flipped) + 3
    # pymavlink's own (non-robust) parser cannot take this stream: that is why we resynchronise
    with pytest.raises(mavlink2.MAVError):
        mavlink2.MAVLink(None).parse_buffer(stream)


def test_stream_feed_waits_for_split_frames() -> None:
    _, frames = _frames()
    data = b"".join(frames)
    dec = MavlinkDecoder()
    got = []
    for k in range(0, len(data), 7):  # 7-byte chunks split every frame
        got += dec.feed(data[k : k + 7])
    assert [m.get_type() for m in got] == ["HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"]
    assert dec.counters.bad_crc == 0 and dec.counters.bad_data == 0


def test_random_bytes_never_raise_and_never_yield_wrong_positions() -> None:
    rng = np.random.default_rng(11)
    ep = MavlinkEndpoint(3, ORIGIN)
    dec = MavlinkDecoder()
    n_good = 0
    for k in range(400):
        frame = bytearray(ep.local_position_ned(0.1 * k, P, V))
        if k % 2:
            for b in rng.integers(0, len(frame) * 8, size=rng.integers(1, 4)):
                frame[b // 8] ^= 1 << (b % 8)
        else:
            n_good += 1
        junk = bytes(rng.integers(0, 256, rng.integers(0, 30), dtype=np.uint8))
        for m in dec.decode_datagram(junk + bytes(frame)):
            if m.get_type() == "LOCAL_POSITION_NED":
                assert np.abs(np.array([m.y, m.x, -m.z]) - P).max() < 0.01
    assert dec.counters.messages >= n_good
    assert dec.counters.bad_crc >= 150  # ~200 corrupted frames, 16-bit CRC


def _link(cfg: ChannelConfig, **kw) -> tuple[Channel, MavlinkLink]:
    ch = Channel(cfg, np.random.default_rng(5))
    link = MavlinkLink(ch, ORIGIN, **kw)
    for u in ("u1", "u2"):
        link.add_uav(u)
    link.add_piloted("c172")
    return ch, link


def _run(link: MavlinkLink, seconds: float, dt: float = 0.05) -> list:
    ids = ["u1", "u2", "c172"]
    pos = np.array([[0.0, 0.0, 30.0], [40.0, 0.0, 30.0], [800.0, 200.0, 300.0]])
    vel = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -50.0, 0.0]])
    inboxes = []
    for k in range(round(seconds / dt)):
        t = k * dt
        link.publish(t, ids, pos + vel * t, vel, np.zeros(3))
        inboxes.append((t, link.receive(t), pos, vel))
    return inboxes


def test_link_over_channel_delivers_reports_with_latency_and_rates() -> None:
    _, link = _link(ChannelConfig(latency_s=0.1, jitter_s=0.0))
    inboxes = _run(link, 10.0)
    u2_reports = [r for _, ib, _, _ in inboxes for r in ib.reports.get("u2", [])]
    from_u1 = [r for r in u2_reports if r.src == "u1"]
    from_c172 = [r for r in u2_reports if r.src == "c172"]
    assert len(from_u1) == pytest.approx(100, abs=2) and len(from_c172) == pytest.approx(100, abs=2)
    for r in from_u1:
        assert r.t_recv_s - r.t_sent_s == pytest.approx(0.1, abs=1e-9)
        assert r.t_meas_s == pytest.approx(r.t_sent_s, abs=1e-3)
        truth = np.array([0.0, 0.0, 30.0]) + np.array([1.0, 0.0, 0.0]) * r.t_sent_s
        assert np.abs(r.p_enu - truth).max() < 0.01
    for r in from_c172:
        truth = np.array([800.0, 200.0, 300.0]) + np.array([0.0, -50.0, 0.0]) * r.t_sent_s
        assert r.kind == "adsb" and np.abs(r.p_enu - truth).max() < 0.02
        assert np.allclose(r.v_enu, [0.0, -50.0, 0.0], atol=0.01)
    assert link.counters().bad_crc == 0


def test_setpoints_reach_only_their_target() -> None:
    ch, link = _link(ChannelConfig(latency_s=0.05, jitter_s=0.0))
    link.command(1.0, "u2", p_enu=np.array([10.0, 20.0, 30.0]), yaw_rad=1.2)
    link.command(1.0, "u1", v_enu=np.array([1.0, 2.0, -0.5]))
    assert link.receive(1.0).setpoints == []
    sps = link.receive(1.05).setpoints
    assert {s.dst for s in sps} == {"u1", "u2"}
    by = {s.dst: s for s in sps}
    assert np.allclose(by["u2"].p_enu, [10, 20, 30]) and by["u2"].v_enu is None
    assert by["u2"].yaw_rad == pytest.approx(1.2, abs=1e-6)
    assert by["u1"].p_enu is None and np.allclose(by["u1"].v_enu, [1.0, 2.0, -0.5])
    assert by["u1"].yaw_rad is None
    assert link.sysid("gcs") == GCS_SYSID


def test_bit_errors_and_injected_garbage_are_counted_not_fatal() -> None:
    rng = np.random.default_rng(2)
    _, link = _link(ChannelConfig(latency_s=0.02, jitter_s=0.0), bit_error_rate=2e-3, rng=rng)
    link.inject(0.0, "u1", b"\x00\x01garbage\xfd\xfe" * 5)
    inboxes = _run(link, 10.0)
    c = link.counters()
    assert link.corrupted_datagrams > 50
    assert c.bad_crc > 30 and c.bad_data >= 1
    n_reports = 0
    for _, ib, pos, vel in inboxes:  # whatever got through is exact
        for r in ib.reports.get("gcs", []):
            n_reports += 1
            k = ["u1", "u2", "c172"].index(r.src)
            assert np.abs(r.p_enu - (pos[k] + vel[k] * r.t_sent_s)).max() < 0.02
    assert n_reports > 200  # most datagrams still arrive (3 senders x ~100 x P(no error))
    stats = link.stats()
    assert stats["mavlink_bad_crc"] == c.bad_crc


def test_loss_on_the_channel_reduces_reports() -> None:
    _, lossless = _link(ChannelConfig(latency_s=0.0, jitter_s=0.0))
    _, lossy = _link(ChannelConfig(latency_s=0.0, jitter_s=0.0, loss=BernoulliLoss(p=0.5)))
    n = [sum(len(ib.reports.get("gcs", [])) for _, ib, _, _ in _run(link, 10.0)) for link in (lossless, lossy)]
    assert n[1] == pytest.approx(0.5 * n[0], rel=0.15)


def test_udp_mirror_sends_every_datagram() -> None:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    port = rx.getsockname()[1]
    try:
        _, link = _link(ChannelConfig(), udp_mirror=f"udpout:127.0.0.1:{port}", rates=LinkRates())
        link.publish(0.0, ["u1"], P[None, :], V[None, :], np.zeros(1))
        data = rx.recv(4096)
        msgs = mavlink2.MAVLink(None).parse_buffer(data)
        assert [m.get_type() for m in msgs] == ["HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"]
        gcs = mavlink2.MAVLink(None).parse_buffer(rx.recv(4096))
        assert gcs[0].get_type() == "HEARTBEAT" and gcs[0].get_srcSystem() == GCS_SYSID
        link.close()
    finally:
        rx.close()
    assert parse_udp_address("udpout:127.0.0.1:14550") == ("127.0.0.1", 14550)
    with pytest.raises(ValueError):
        parse_udp_address("tcp:1.2.3.4")


def test_shared_decode_gives_every_receiver_what_its_own_parse_gives() -> None:
    """receive() decodes each distinct datagram once and shares the result among its receivers: the
    reports and counters must equal those of parsing every delivered copy on its own."""
    ch, link = _link(ChannelConfig(latency_s=0.05, jitter_s=0.03, loss=BernoulliLoss(p=0.1)))
    ids = ["u1", "u2", "c172"]
    pos = np.array([[0.0, 0.0, 30.0], [40.0, 0.0, 30.0], [800.0, 200.0, 300.0]])
    vel = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -50.0, 0.0]])
    own: dict[str, list[tuple]] = {}  # per receiver: (t_recv, src, send order, report)
    ref_counts = MavlinkDecoder()  # one decoder fed every copy: the per-copy counters summed
    original_deliver = ch.deliver_indexed

    def deliver_and_parse(t_s: float) -> list:
        out = original_deliver(t_s)
        for b in out:  # the reference: a fresh decode per copy, per-copy conversion
            for i, t_recv in zip(b.dst_idx.tolist(), b.t_recv_s.tolist(), strict=True):
                msgs = ref_counts.decode_datagram(b.payload)
                r = report_from_messages(msgs, ORIGIN, b.src, b.t_sent_s, t_recv)
                if r is not None:
                    own.setdefault(ch.node_names[i], []).append((t_recv, b.src, b.seq, r))
        return out

    ch.deliver_indexed = deliver_and_parse
    shared: dict[str, list] = {}
    for k in range(50):
        t = k * 0.1
        link.publish(t, ids, pos + vel * t, vel, np.zeros(3))
        for dst, reports in link.receive(t).reports.items():
            shared.setdefault(dst, []).extend(reports)
    assert set(shared) == set(own) and sum(map(len, shared.values())) > 100
    for dst in own:
        assert len(shared[dst]) == len(own[dst])
        in_delivery_order = [r for *_, r in sorted(own[dst], key=lambda c: c[:3])]
        for a, b in zip(shared[dst], in_delivery_order, strict=True):
            assert (a.src, a.sysid, a.kind, a.t_sent_s, a.t_recv_s, a.t_meas_s) == (
                b.src, b.sysid, b.kind, b.t_sent_s, b.t_recv_s, b.t_meas_s)
            assert np.array_equal(a.p_enu, b.p_enu) and np.array_equal(a.v_enu, b.v_enu)
            assert a.yaw_rad == b.yaw_rad or (np.isnan(a.yaw_rad) and np.isnan(b.yaw_rad))
    assert link.counters() == ref_counts.counters  # counters still count every received copy
    assert ref_counts.counters.messages > sum(map(len, own.values()))  # heartbeats are not reports


@pytest.mark.parametrize("ber", [0.0, 2e-4])
def test_receive_latest_table_keeps_what_receive_would_keep(ber: float) -> None:
    """The array form (LatestReports, one pass per datagram over its receivers) keeps, per (receiver,
    source), the newest report of those ``receive`` hands out (equal measurement times: the later
    delivered), routes the same set-points and counts every copy, with and without bit errors (then
    copy by copy): both read the link's one receive path."""
    cfg = ChannelConfig(latency_s=0.05, jitter_s=0.08, loss=BernoulliLoss(p=0.1))  # jitter reorders
    kw = {"bit_error_rate": ber, "rng": np.random.default_rng(3)} if ber else {}
    (_, ref), (_, arr) = _link(cfg, **kw), _link(cfg, **({**kw, "rng": np.random.default_rng(3)} if ber else {}))
    ids = ["u1", "u2", "c172"]
    pos = np.array([[0.0, 0.0, 30.0], [40.0, 0.0, 30.0], [800.0, 200.0, 300.0]])
    vel = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -50.0, 0.0]])
    rx, src = ["u1", "u2"], ["u1", "u2", "c172"]
    table = arr.latest_table(rx, src)
    latest: dict[str, dict] = {"u1": {}, "u2": {}}
    seen = setpoints = 0
    for k in range(80):
        t = 0.05 * k
        for link in (ref, arr):
            link.publish(t, ids, pos + vel * t, vel, np.zeros(3))
            if 10 <= k < 20:
                link.command(t, "u2", v_enu=np.array([1.0, 2.0, float(k)]))
        got, inbox = arr.receive_latest_table(t, table), ref.receive(t)
        want_sp = inbox.setpoints
        assert [(s.dst, s.t_recv_s, s.v_enu.tolist()) for s in got] == [(s.dst, s.t_recv_s, s.v_enu.tolist()) for s in want_sp]
        for dst in rx:
            for r in inbox.reports.get(dst, []):  # delivery order: the later delivered wins a tie
                old = latest[dst].get(r.src)
                if old is None or r.t_meas_s >= old.t_meas_s:
                    latest[dst][r.src] = r
        setpoints += len(got)
        for r, dst in enumerate(rx):
            assert {src[c] for c in range(len(src)) if table.fresh[r, c]} == set(latest[dst])
            for c, s in enumerate(src):
                if table.fresh[r, c]:
                    want = latest[dst][s]
                    assert (table.t_meas_s[r, c], table.t_recv_s[r, c]) == (want.t_meas_s, want.t_recv_s)
                    assert np.array_equal(table.p_enu[r, c], want.p_enu)
                    assert np.array_equal(table.v_enu[r, c], want.v_enu)
                    seen += 1
        if k % 4 == 3:  # a consumer fuses and clears now and then
            table.fresh[:] = False
            for d in latest.values():
                d.clear()
    assert seen > 100 and (setpoints >= 5 or ber > 0.0)
    assert arr.counters() == ref.counters() and ref.counters().messages > 100
