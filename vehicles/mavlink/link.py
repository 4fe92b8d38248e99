"""MAVLink 2 link between aircraft and a ground station, carried as bytes over ``corridor.channel``.

Every UAV is a MAVLink system (its own ``sysid``) that sends HEARTBEAT at 1 Hz and
GLOBAL_POSITION_INT + LOCAL_POSITION_NED at 10 Hz; a piloted aircraft is seen through ADSB_VEHICLE
(as if re-broadcast by an ADS-B receiver); the ground station (sysid 255) sends HEARTBEAT and
SET_POSITION_TARGET_LOCAL_NED commands.  Encoding is :mod:`corridor.vehicles.mavlink.encode`,
decoding :mod:`corridor.vehicles.mavlink.decode` (pymavlink's, dialect ``common``, MAVLink 2 framing).

Frames due at the same instant from one sender travel in one datagram (one ``channel.send``), as on
UDP.  Receiving has one path (:meth:`MavlinkLink._copies`): the delivered copies, grouped by shared
decode, which :meth:`MavlinkLink.receive` hands out as traffic reports per receiver and
:meth:`MavlinkLink.receive_latest_table` folds into the newest report per receiver and source.
"""

from __future__ import annotations

import math
import socket
from collections.abc import Iterable
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from corridor.vehicles.geodesy import Origin
from corridor.vehicles.mavlink.decode import (
    DecodeCounters,
    Decoded,
    MavlinkDecoder,
    Setpoint,
    TrafficReport,
    setpoint_from_message,
)
from corridor.vehicles.mavlink.encode import GCS_SYSID, MavlinkEndpoint


class LatestReports:
    """The newest report per (receiver, source) not yet consumed, as arrays: what
    :meth:`MavlinkLink.receive_latest_table` fills and a consumer (``AirLink``) reads and clears.

    Rows are ``receivers``, columns ``sources`` (link member ids). ``fresh[r, s]``: a report is
    pending; ``t_meas_s`` / ``t_recv_s`` [s], ``p_enu`` [m] / ``v_enu`` [m/s] (n_rx, n_src, 3) its
    content; ``first`` the order in which pairs became fresh (the insertion order of
    :meth:`MavlinkLink.receive_latest`'s dicts)."""

    def __init__(self, receivers: list[str], sources: list[str]) -> None:
        self.receivers, self.sources = list(receivers), list(sources)
        n_rx, n_src = len(receivers), len(sources)
        self.fresh = np.zeros((n_rx, n_src), dtype=bool)
        self.t_meas_s = np.zeros((n_rx, n_src))
        self.t_recv_s = np.zeros((n_rx, n_src))
        self.p_enu = np.zeros((n_rx, n_src, 3))
        self.v_enu = np.zeros((n_rx, n_src, 3))
        self.first = np.zeros((n_rx, n_src), dtype=np.int64)
        self.counter = 0

    def copy(self) -> LatestReports:
        out = LatestReports.__new__(LatestReports)
        out.__dict__.update({k: (v.copy() if isinstance(v, np.ndarray | list) else v) for k, v in self.__dict__.items()})
        return out

    def offer(self, rows: np.ndarray, col: int, t_meas_s: float, t_recv_s: np.ndarray, p: np.ndarray,
              v: np.ndarray) -> None:
        """One datagram's copies at receivers ``rows`` (distinct): kept where no report is pending or
        it is not older than the pending one (equal measurement times: the later-delivered one)."""
        fresh = self.fresh[rows, col]
        old_t, old_r = self.t_meas_s[rows, col], self.t_recv_s[rows, col]
        take = ~fresh | (t_meas_s > old_t) | ((t_meas_s == old_t) & (t_recv_s >= old_r))
        if not take.all():
            rows, t_recv_s, fresh = rows[take], t_recv_s[take], fresh[take]
        self.first[rows[~fresh], col] = self.counter
        self.counter += 1
        self.fresh[rows, col] = True
        self.t_meas_s[rows, col] = t_meas_s
        self.t_recv_s[rows, col] = t_recv_s
        self.p_enu[rows, col] = p
        self.v_enu[rows, col] = v


class _Copy(NamedTuple):
    """Where one received copy came from and when (the fields of a channel delivery used here)."""

    src: str
    dst: str
    t_sent_s: float
    t_recv_s: float


class _Copies(NamedTuple):
    """The copies of one datagram that share one decode: sender, send time and order, and its
    receivers (channel node indices of listening members) with their receive times."""

    src: str
    t_sent_s: float  # [s]
    seq: int  # send order (ties in the channel's delivery order)
    decoded: Decoded
    dst_idx: np.ndarray  # node indices (``channel.node_names``)
    t_recv_s: np.ndarray  # [s] per receiver


@dataclass(frozen=True)
class LinkRates:
    """Send rates [Hz]: HEARTBEAT, UAV position (GLOBAL_POSITION_INT + LOCAL_POSITION_NED), ADS-B."""

    heartbeat_hz: float = 1.0
    position_hz: float = 10.0
    adsb_hz: float = 10.0


@dataclass
class Inbox:
    """What one ``receive`` call delivered: traffic reports per receiver, set-points per target."""

    reports: dict[str, list[TrafficReport]] = field(default_factory=dict)
    setpoints: list[Setpoint] = field(default_factory=list)


def parse_udp_address(addr: str) -> tuple[str, int]:
    """``"udpout:127.0.0.1:14550"`` (or ``"127.0.0.1:14550"``) -> (host, port)."""
    parts = addr.split(":")
    if parts[0] in ("udpout", "udp"):
        parts = parts[1:]
    if len(parts) != 2:
        raise ValueError(f"expected udpout:HOST:PORT, got {addr!r}")
    return parts[0], int(parts[1])


@dataclass
class _Node:
    endpoint: MavlinkEndpoint
    kind: str  # "uav" | "piloted" | "gcs"
    icao: int = 0
    callsign: str = ""
    next_hb_s: float = 0.0
    next_pos_s: float = 0.0


class MavlinkLink:
    """All MAVLink traffic of a scenario over one channel (``corridor.channel.Channel`` interface:
    ``attach``, ``send(t_s, src, payload, src_pos=None, dst=None)``, ``deliver(t_s)``).

    Per tick: ``publish(t_s, ids, position, velocity, yaw)`` sends what is due; ``command(...)`` sends a
    ground-station set-point; ``receive(t_s)`` decodes what the channel delivered. ``bit_error_rate``
    flips received bits (per bit, drawn from ``rng``) to exercise the CRC; ``udp_mirror`` copies every
    sent datagram to a UDP address (e.g. ``"udpout:127.0.0.1:14550"`` for QGroundControl);
    ``log_path`` writes every sent byte to a raw MAVLink file.
    """

    def __init__(
        self,
        channel: Any,
        origin: Origin | tuple[float, float, float],
        rates: LinkRates | None = None,
        gcs_id: str = "gcs",
        udp_mirror: str | None = None,
        log_path: str | None = None,
        bit_error_rate: float = 0.0,
        rng: np.random.Generator | None = None,
        dialect: ModuleType | None = None,
    ) -> None:
        self.channel = channel
        self.dialect = dialect  # None: pymavlink's common; else a generated superset (corridor.vehicles.mavlink.dialect)
        # TRAFFIC_SEGMENT_ESTIMATE messages the ground station received: (t_recv [s], src, t_sent [s], msg)
        self.estimates: list[tuple[float, str, float, Any]] = []
        self.origin = origin if isinstance(origin, Origin) else Origin(*origin)
        self.rates = rates or LinkRates()
        self.gcs_id = gcs_id
        self.bit_error_rate = bit_error_rate
        if bit_error_rate > 0.0 and rng is None:
            raise ValueError("bit_error_rate > 0 needs an rng (numpy.random.Generator)")
        self._rng = rng
        self._nodes: dict[str, _Node] = {}
        self._by_sysid: dict[int, str] = {}
        self._decoders: dict[str, MavlinkDecoder] = {}
        self._cache: dict[bytes, Decoded] = {}
        self._tally: dict[tuple[int, int, int, int], np.ndarray] = {}  # counter key -> copies per node index
        self._listen: np.ndarray | None = None  # per node index: a listening member
        self._rx_of_node = np.zeros(0, dtype=np.int64)  # node index -> LatestReports row (-1: none)
        self._src_col: dict[str, int] = {}  # link member -> LatestReports column
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM) if udp_mirror else None
        self._udp_addr = parse_udp_address(udp_mirror) if udp_mirror else None
        self._log = open(log_path, "wb") if log_path else None  # noqa: SIM115 - closed in close()
        self.sent_datagrams = 0
        self.sent_bytes = 0
        self.corrupted_datagrams = 0
        self._add(gcs_id, GCS_SYSID, "gcs", mavlink2.MAV_TYPE_GCS, listen=True)

    # -------------------------------------------------------------------------------- membership
    def _add(self, id: str, sysid: int, kind: str, mav_type: int, listen: bool, **kw: Any) -> int:
        if id in self._nodes or sysid in self._by_sysid:
            raise ValueError(f"duplicate link member {id!r} / sysid {sysid}")
        self._fold_tallies()
        self._listen = None
        self._nodes[id] = _Node(MavlinkEndpoint(sysid, self.origin, mav_type=mav_type, dialect=self.dialect),
                                kind, **kw)
        self._by_sysid[sysid] = id
        if listen:
            self.channel.attach(id)
            self._decoders[id] = MavlinkDecoder(self.dialect)
        return sysid

    def _free_sysid(self) -> int:
        return next(s for s in range(1, 255) if s not in self._by_sysid)

    def add_uav(self, id: str, sysid: int | None = None) -> int:
        """Register a UAV (sends telemetry, receives traffic and set-points); returns its sysid."""
        return self._add(id, sysid or self._free_sysid(), "uav", mavlink2.MAV_TYPE_QUADROTOR, listen=True)

    def add_piloted(self, id: str, icao: int | None = None, callsign: str | None = None) -> int:
        """Register a piloted aircraft seen through ADSB_VEHICLE (it does not listen); returns its sysid."""
        sysid = self._free_sysid()
        return self._add(
            id, sysid, "piloted", mavlink2.MAV_TYPE_FIXED_WING, listen=False,
            icao=icao if icao is not None else 0xC0FFEE + sysid, callsign=callsign or id.upper()[:8],
        )

    def sysid(self, id: str) -> int:
        """MAVLink system id of link member ``id``."""
        return self._nodes[id].endpoint.sysid

    # -------------------------------------------------------------------------------- sending
    def _send(
        self, t_s: float, src: str, payload: bytes, src_pos: np.ndarray | None, dst: str | None = None
    ) -> None:
        self.channel.send(t_s, src, payload, src_pos=src_pos, dst=dst)
        self._sent(payload)

    def _sent(self, payload: bytes) -> None:
        """Counters, UDP mirror and byte log of one datagram handed to the channel."""
        self.sent_datagrams += 1
        self.sent_bytes += len(payload)
        if self._udp is not None:
            self._udp.sendto(payload, self._udp_addr)
        if self._log is not None:
            self._log.write(payload)

    def publish(
        self, t_s: float, ids: Iterable[str], position: np.ndarray, velocity: np.ndarray, yaw: np.ndarray
    ) -> None:
        """Send every message due at ``t_s`` for the registered aircraft among ``ids`` (struct of
        arrays in ENU, e.g. a WorldSnapshot's ids/position/velocity/heading); the GCS heartbeat too.
        The geodetic conversion is done once for the whole fleet (vectorised), and the datagrams of
        this instant go to the channel in one ``send_many`` when it has one (same draws and order)."""
        pos = np.asarray(position, float).reshape(-1, 3)
        lat, lon, h = self.origin.to_geodetic(pos)
        rows = zip(ids, pos, np.asarray(velocity, float).reshape(-1, 3).tolist(), np.asarray(yaw, float).tolist(),
                   zip(lat.tolist(), lon.tolist(), h.tolist()), strict=True)
        out: list[tuple[str, bytes, np.ndarray | None, str | None]] = []
        for id, p, v, yaw_k, geo in rows:
            node = self._nodes.get(str(id))
            if node is not None and node.kind != "gcs":
                payload = self._publish_one(t_s, node, p, v, yaw_k, geo)
                if payload:
                    out.append((str(id), payload, p, None))
        gcs = self._nodes[self.gcs_id]
        if t_s + 1e-9 >= gcs.next_hb_s:
            gcs.next_hb_s = _next_due(gcs.next_hb_s, t_s, 1.0 / self.rates.heartbeat_hz)
            out.append((self.gcs_id, gcs.endpoint.heartbeat(), None, None))
        send_many = getattr(self.channel, "send_many", None)
        if send_many is None:
            for src, payload, p, _ in out:
                self._send(t_s, src, payload, p)
            return
        send_many(t_s, out)
        for _, payload, _, _ in out:
            self._sent(payload)

    def _publish_one(
        self, t_s: float, node: _Node, p: np.ndarray, v: list[float], yaw: float, geo: tuple[float, float, float]
    ) -> bytes:
        """The datagram one aircraft owes at ``t_s`` (b"" if nothing is due)."""
        ep, frames = node.endpoint, []
        if node.kind == "uav" and t_s + 1e-9 >= node.next_hb_s:
            node.next_hb_s = _next_due(node.next_hb_s, t_s, 1.0 / self.rates.heartbeat_hz)
            frames.append(ep.heartbeat())
        rate = self.rates.position_hz if node.kind == "uav" else self.rates.adsb_hz
        if t_s + 1e-9 >= node.next_pos_s:
            node.next_pos_s = _next_due(node.next_pos_s, t_s, 1.0 / rate)
            if node.kind == "uav":
                frames += [ep.global_position_int(t_s, p, v, yaw, geo), ep.local_position_ned(t_s, p, v)]
            else:
                frames.append(ep.adsb_vehicle(node.icao, node.callsign, p, v, geodetic=geo))
        return b"".join(frames)

    def command(
        self,
        t_s: float,
        target_id: str,
        p_enu: np.ndarray | None = None,
        v_enu: np.ndarray | None = None,
        yaw_rad: float | None = None,
    ) -> None:
        """Ground station -> ``target_id``: SET_POSITION_TARGET_LOCAL_NED (unicast)."""
        gcs = self._nodes[self.gcs_id].endpoint
        payload = gcs.set_position_target_local_ned(t_s, self.sysid(target_id), p_enu, v_enu, yaw_rad)
        self._send(t_s, self.gcs_id, payload, None, dst=target_id)

    def send_to_gcs(self, t_s: float, src: str, messages: Iterable[Any], src_pos: np.ndarray | None = None) -> int:
        """``src`` -> ground station: the given pymavlink messages (of this link's dialect) framed by
        ``src``'s endpoint in one unicast datagram; returns its size [bytes] (0: nothing sent)."""
        ep = self._nodes[src].endpoint
        payload = b"".join(ep.pack(m) for m in messages)
        if payload:
            self._send(t_s, src, payload, src_pos, dst=self.gcs_id)
        return len(payload)

    def endpoint(self, id: str) -> MavlinkEndpoint:
        """The MAVLink endpoint of link member ``id`` (its ``mav`` builds messages of the dialect)."""
        return self._nodes[id].endpoint

    def inject(self, t_s: float, src: str, payload: bytes, dst: str | None = None) -> None:
        """Put raw bytes (garbage, a hand-made frame) on the channel as if ``src`` had sent them."""
        self._send(t_s, src, bytes(payload), None, dst=dst)

    # -------------------------------------------------------------------------------- receiving
    def receive(self, t_s: float) -> Inbox:
        """Deliver, corrupt (if configured), decode; traffic reports and set-points of this instant,
        every copy in the channel's delivery order (by receive time, sender, receiver, send order).

        A broadcast datagram reaches many receivers as copies of the same bytes: each distinct payload
        is decoded and converted once per call (:class:`Decoded`), and its receivers share the result
        (the counters are still added per received copy, as if every receiver had parsed it)."""
        inbox = Inbox()
        names = self.channel.node_names
        copies = [(t_recv, c.src, names[i], c.seq, c) for c in self._copies(t_s)
                  for i, t_recv in zip(c.dst_idx.tolist(), c.t_recv_s.tolist(), strict=True)]
        for t_recv, src, dst, _, c in sorted(copies, key=lambda r: r[:4]):
            rep = c.decoded.report
            if rep is not None:
                inbox.reports.setdefault(dst, []).append(rep.received(src, c.t_sent_s, t_recv))
            if c.decoded.setpoints:
                self._route_setpoints(inbox, _Copy(src, dst, c.t_sent_s, t_recv), c.decoded)
            if c.decoded.estimates and dst == self.gcs_id:
                self.estimates.extend((t_recv, src, c.t_sent_s, m) for m in c.decoded.estimates)
        return inbox

    def latest_table(self, receivers: list[str], sources: list[str]) -> LatestReports:
        """An empty :class:`LatestReports` for ``receivers`` (listening members) x ``sources``."""
        table = LatestReports(receivers, sources)
        ch = self.channel
        n = max(ch.node_index(i) for i in [*self._nodes, *receivers, *sources]) + 1
        self._rx_of_node = np.full(n, -1, dtype=np.int64)
        self._src_col = {id: k for k, id in enumerate(sources)}
        for k, id in enumerate(receivers):
            self._rx_of_node[ch.node_index(id)] = k
        return table

    def receive_latest_table(self, t_s: float, table: LatestReports) -> list[Setpoint]:
        """:meth:`receive` for consumers that keep only the newest report per (receiver, source), in a
        :class:`LatestReports` (made by :meth:`latest_table`): the same deliveries, decoding and
        counters, with the copies of a datagram handled as arrays (receiver rows, receive times)
        instead of a :class:`TrafficReport` per copy (a swarm's broadcasts are N^2 copies per tick).
        Of several reports with the same measurement time the later-delivered one is kept, as in
        delivery order.  Returns the set-points (in delivery order)."""
        copies = self._copies(t_s)
        if self._rx_of_node.size < len(self.channel.node_names):  # nodes the channel learnt after latest_table
            self._rx_of_node = np.r_[self._rx_of_node,
                                     np.full(len(self.channel.node_names) - self._rx_of_node.size, -1)]
        rx_of, names, routed = self._rx_of_node, self.channel.node_names, []
        for c in copies:
            rep, col = c.decoded.report, self._src_col.get(c.src)
            if rep is not None and col is not None:
                rows = rx_of[c.dst_idx]
                keep = rows >= 0
                t_meas = c.t_sent_s - rep.tslc_s if rep.kind == "adsb" else rep.t_meas_s
                table.offer(rows[keep], col, t_meas, c.t_recv_s[keep], rep.p_enu, rep.v_enu)
            if c.decoded.setpoints or c.decoded.estimates:
                for i, t_recv in zip(c.dst_idx.tolist(), c.t_recv_s.tolist(), strict=True):
                    if c.decoded.setpoints:
                        routed.append((t_recv, c.src, names[i], c.seq, c))
                    if c.decoded.estimates and names[i] == self.gcs_id:  # camera estimates for the ground station
                        self.estimates.extend((t_recv, c.src, c.t_sent_s, m) for m in c.decoded.estimates)
        inbox = Inbox()
        for t_recv, src, dst, _, c in sorted(routed, key=lambda r: r[:4]):  # delivery order
            self._route_setpoints(inbox, _Copy(src, dst, c.t_sent_s, t_recv), c.decoded)
        return inbox.setpoints

    def _copies(self, t_s: float) -> list[_Copies]:
        """The one receive path: the copies delivered at ``t_s`` to listening members, grouped by
        shared decode, with each copy counted in its receiver's decoder.

        Without bit errors every copy of a datagram carries the same bytes: the channel's batches (one
        per sent message, in send order) are decoded once each.  With bit errors each copy's bytes may
        differ: the copies are taken in the channel's delivery order and each is corrupted and decoded
        on its own (a group of one)."""
        self._cache.clear()
        out: list[_Copies] = []
        if self.bit_error_rate > 0.0:
            index = self.channel.node_index
            for seq, d in enumerate(self.channel.deliver(t_s)):
                if d.dst not in self._decoders:
                    continue
                hit = self._decoded(d.payload, corrupt=True)
                if hit is not None:
                    out.append(_Copies(d.src, d.t_sent_s, seq, hit, np.array([index(d.dst)]), np.array([d.t_recv_s])))
        else:
            batches = self.channel.deliver_indexed(t_s)
            listen = self._listening_nodes()
            for b in batches:
                hit = self._decoded(b.payload)
                if hit is not None:
                    keep = listen[b.dst_idx]
                    out.append(_Copies(b.src, b.t_sent_s, b.seq, hit, b.dst_idx[keep], b.t_recv_s[keep]))
        listen = self._listening_nodes()
        tally = self._tally
        for c in out:
            counts = tally.get(c.decoded.counter_key)
            if counts is None:
                counts = tally[c.decoded.counter_key] = np.zeros(listen.size, dtype=np.int64)
            np.add.at(counts, c.dst_idx, 1)
        return out

    def _listening_nodes(self) -> np.ndarray:
        """Bool per channel node index: a listening link member (its copies are counted)."""
        names = self.channel.node_names
        if self._listen is None or self._listen.size != len(names):
            self._fold_tallies()
            self._listen = np.array([n in self._decoders for n in names], dtype=bool)
        return self._listen

    def _fold_tallies(self) -> None:
        """Add the per-node copy tallies of :meth:`receive_latest_table` to the receivers' decoders."""
        if not self._tally:
            return
        names = self.channel.node_names
        for key, counts in self._tally.items():
            for i in np.flatnonzero(counts).tolist():
                shared = self._decoders[names[i]]._shared
                shared[key] = shared.get(key, 0) + int(counts[i])
        self._tally = {}

    def _corrupt(self, payload: bytes) -> bytes:
        if self.bit_error_rate <= 0.0:
            return payload
        n_bits = len(payload) * 8
        k = int(self._rng.binomial(n_bits, self.bit_error_rate))
        if k == 0:
            return payload
        self.corrupted_datagrams += 1
        buf = bytearray(payload)
        for b in self._rng.choice(n_bits, size=k, replace=False):
            buf[b // 8] ^= 1 << (b % 8)
        return bytes(buf)

    def _decoded(self, payload: Any, corrupt: bool = False) -> Decoded | None:
        """The decode of a datagram's bytes (after bit errors if ``corrupt``), memoised within one
        receive for copies of the same bytes; None if the payload is not bytes."""
        if not isinstance(payload, bytes | bytearray):
            return None
        if type(payload) is not bytes:
            payload = bytes(payload)
        if corrupt:
            payload = self._corrupt(payload)
        hit = self._cache.get(payload)
        if hit is None:
            hit = self._cache[payload] = self._decode_once(payload)
        return hit

    def _decode_once(self, payload: bytes) -> Decoded:
        """Datagram decode + conversion (memoised within one receive for copies of the same bytes)."""
        scratch = MavlinkDecoder(self.dialect)
        msgs = scratch.decode_datagram(payload)
        return Decoded.of(msgs, scratch.counters, self.origin)

    def _route_setpoints(self, inbox: Inbox, d: Any, decoded: Decoded) -> None:
        my_sysid = self._nodes[d.dst].endpoint.sysid
        for m in decoded.setpoints:
            if m.target_system == my_sysid:
                inbox.setpoints.append(setpoint_from_message(m, d.dst, d.t_sent_s, d.t_recv_s))

    # -------------------------------------------------------------------------------- statistics
    def counters(self) -> DecodeCounters:
        """Decode counters summed over every receiver."""
        self._fold_tallies()
        total = DecodeCounters()
        for dec in self._decoders.values():
            total.add(dec.counters)
        return total

    def stats(self, prefix: str = "mavlink_") -> dict[str, float]:
        """Flat link statistics for a results row."""
        c = self.counters()
        return {
            prefix + "sent_datagrams": float(self.sent_datagrams),
            prefix + "sent_bytes": float(self.sent_bytes),
            prefix + "messages": float(c.messages),
            prefix + "bad_crc": float(c.bad_crc),
            prefix + "bad_data": float(c.bad_data),
            prefix + "bytes_dropped": float(c.bytes_dropped),
            prefix + "corrupted_datagrams": float(self.corrupted_datagrams),
        }

    def close(self) -> None:
        """Close the UDP mirror socket and the byte log."""
        if self._udp is not None:
            self._udp.close()
            self._udp = None
        if self._log is not None:
            self._log.close()
            self._log = None


def _next_due(prev_due_s: float, t_s: float, period_s: float) -> float:
    """Next send time on the grid prev_due + k * period strictly after ``t_s``."""
    k = math.floor((t_s - prev_due_s) / period_s + 1e-9) + 1.0
    return prev_due_s + max(k, 1.0) * period_s
