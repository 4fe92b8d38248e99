"""MAVLink 2 link between aircraft and a ground station, carried as bytes over ``corridor.channel``.

Every UAV is a MAVLink system (its own ``sysid``) that sends HEARTBEAT at 1 Hz and
GLOBAL_POSITION_INT + LOCAL_POSITION_NED at 10 Hz; a piloted aircraft is seen through ADSB_VEHICLE
(as if re-broadcast by an ADS-B receiver); the ground station (sysid 255) sends HEARTBEAT and
SET_POSITION_TARGET_LOCAL_NED commands. Encoding and decoding are pymavlink's (dialect ``common``,
MAVLink 2 framing, magic 0xFD, CRC-16/X.25 with CRC_EXTRA).

Frames due at the same instant from one sender travel in one datagram (one ``channel.send``), as on
UDP. Each received datagram is parsed on its own (:meth:`MavlinkDecoder.decode_datagram`): a frame
whose CRC does not match is counted in ``bad_crc`` and the parser resynchronises at the next 0xFD
byte; bytes that are not a frame (garbage, truncated frames, unknown message ids, bad flags) are
counted in ``bad_data``. Nothing corrupted can raise. One corrupted frame can add more than one count
when its body happens to contain 0xFD bytes (each candidate start is checked, as the C library does).

Frames: local NED is the scenario's ENU origin (x north, y east, z down); altitudes in
GLOBAL_POSITION_INT / ADSB_VEHICLE are heights above the WGS-84 ellipsoid (no geoid model; the
scenario origin's height defines the datum), ``relative_alt`` is ENU up.
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

from corridor.vehicles.geodesy import Origin, heading_from_enu_yaw, wrap_pi

MAGIC_V2 = mavlink2.PROTOCOL_MARKER_V2  # 0xFD
_HEADER_LEN = mavlink2.HEADER_LEN_V2  # 10 bytes
_SIGNATURE_LEN = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN  # 13 bytes
GCS_SYSID = 255
_TM_IGNORE_POS = 0b111  # POSITION_TARGET_TYPEMASK_{X,Y,Z}_IGNORE
_TM_IGNORE_VEL = 0b111000
_TM_IGNORE_ACC = 0b111000000
_TM_IGNORE_YAW = mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
_TM_IGNORE_YAW_RATE = mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE


def _ms(t_s: float) -> int:
    """Simulation time [s] -> MAVLink time_boot_ms (uint32, wraps)."""
    return int(round(t_s * 1000.0)) & 0xFFFFFFFF


_TWO_PI = 2.0 * math.pi


def _cdeg(yaw_rad: float) -> int:
    """ENU yaw [rad] -> compass heading in centidegrees [0, 35999].

    ``heading_from_enu_yaw`` and ``np.degrees`` on a plain float, written with ``math`` (the same
    IEEE operations: Python's float ``%`` and numpy's ``mod`` both are fmod plus a sign fix-up)."""
    return round(math.degrees((0.5 * math.pi - float(yaw_rad)) % _TWO_PI) * 100.0) % 36000


# ------------------------------------------------------------------------------------------ encoding
class MavlinkEndpoint:
    """One MAVLink 2 system/component: turns states and commands into framed bytes.

    ``origin`` anchors the local NED frame and the geodetic conversion.
    """

    def __init__(self, sysid: int, origin: Origin, compid: int = 1, mav_type: int = mavlink2.MAV_TYPE_QUADROTOR,
                 dialect: ModuleType | None = None):
        if not 1 <= sysid <= 255:
            raise ValueError(f"MAVLink sysid must be in 1..255, got {sysid}")
        self.sysid, self.compid, self.mav_type = sysid, compid, mav_type
        self.origin = origin
        self.mav = (dialect or mavlink2).MAVLink(None, srcSystem=sysid, srcComponent=compid)

    def pack(self, msg: Any) -> bytes:
        """Frame one message with this endpoint's ids and sequence number (MAVLink 2, 0xFD)."""
        buf = bytes(msg.pack(self.mav))  # pack() does not advance the sequence number: we do
        self.mav.seq = (self.mav.seq + 1) % 256
        self.mav.total_packets_sent += 1
        self.mav.total_bytes_sent += len(buf)
        return buf

    def heartbeat(self) -> bytes:
        """HEARTBEAT: a GCS reports MAV_TYPE_GCS / no autopilot; aircraft report guided + armed."""
        autopilot = mavlink2.MAV_AUTOPILOT_INVALID if self.mav_type == mavlink2.MAV_TYPE_GCS else (
            mavlink2.MAV_AUTOPILOT_GENERIC
        )
        mode = 0 if self.mav_type == mavlink2.MAV_TYPE_GCS else (
            mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        )
        return self.pack(self.mav.heartbeat_encode(self.mav_type, autopilot, mode, 0, mavlink2.MAV_STATE_ACTIVE))

    def global_position_int(
        self, t_s: float, p_enu: np.ndarray, v_enu: np.ndarray, yaw_rad: float,
        geodetic: tuple[float, float, float] | None = None,
    ) -> bytes:
        """GLOBAL_POSITION_INT: lat/lon [1e-7 deg], alt [mm], relative_alt = ENU up [mm], NED cm/s.

        ``geodetic`` = (lat [deg], lon [deg], h [m]) of ``p_enu`` when the caller converted a whole
        fleet at once (the per-message conversion is the costly part of encoding)."""
        lat, lon, h = geodetic if geodetic is not None else self.origin.to_geodetic(np.asarray(p_enu, float))
        ve, vn, vu = _floats3(v_enu)
        msg = self.mav.global_position_int_encode(
            _ms(t_s), round(float(lat) * 1e7), round(float(lon) * 1e7), round(float(h) * 1e3),
            round(float(p_enu[2]) * 1e3), _cm_s(vn), _cm_s(ve), _cm_s(-vu), _cdeg(yaw_rad),
        )
        return self.pack(msg)

    def local_position_ned(self, t_s: float, p_enu: np.ndarray, v_enu: np.ndarray) -> bytes:
        """LOCAL_POSITION_NED around the scenario origin [m, m/s]."""
        e, n, u = _floats3(p_enu)
        ve, vn, vu = _floats3(v_enu)
        return self.pack(self.mav.local_position_ned_encode(_ms(t_s), n, e, -u, vn, ve, -vu))

    def adsb_vehicle(
        self, icao: int, callsign: str, p_enu: np.ndarray, v_enu: np.ndarray, tslc_s: int = 0,
        geodetic: tuple[float, float, float] | None = None,
    ) -> bytes:
        """ADSB_VEHICLE report of a piloted aircraft (geometric altitude, course over ground);
        ``geodetic`` as in :meth:`global_position_int`."""
        lat, lon, h = geodetic if geodetic is not None else self.origin.to_geodetic(np.asarray(p_enu, float))
        ve, vn, vu = (float(x) for x in v_enu)
        flags = (
            mavlink2.ADSB_FLAGS_VALID_COORDS | mavlink2.ADSB_FLAGS_VALID_ALTITUDE
            | mavlink2.ADSB_FLAGS_VALID_HEADING | mavlink2.ADSB_FLAGS_VALID_VELOCITY
            | mavlink2.ADSB_FLAGS_VALID_CALLSIGN
        )
        msg = self.mav.adsb_vehicle_encode(
            icao & 0xFFFFFFFF, int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)),
            mavlink2.ADSB_ALTITUDE_TYPE_GEOMETRIC, int(round(float(h) * 1e3)),
            _cdeg(float(np.arctan2(vn, ve))), min(int(round(np.hypot(ve, vn) * 100.0)), 0xFFFF),
            _cm_s(vu), callsign.encode()[:8], mavlink2.ADSB_EMITTER_TYPE_LIGHT, min(tslc_s, 255), flags, 1200,
        )
        return self.pack(msg)

    def set_position_target_local_ned(
        self,
        t_s: float,
        target_sysid: int,
        p_enu: np.ndarray | None = None,
        v_enu: np.ndarray | None = None,
        yaw_rad: float | None = None,
    ) -> bytes:
        """SET_POSITION_TARGET_LOCAL_NED to ``target_sysid``; omitted parts are masked as ignored."""
        mask = _TM_IGNORE_ACC | _TM_IGNORE_YAW_RATE
        p, v = np.zeros(3), np.zeros(3)
        if p_enu is None:
            mask |= _TM_IGNORE_POS
        else:
            p = np.asarray(p_enu, float)
        if v_enu is None:
            mask |= _TM_IGNORE_VEL
        else:
            v = np.asarray(v_enu, float)
        yaw_ned = 0.0 if yaw_rad is None else float(wrap_pi(heading_from_enu_yaw(yaw_rad)))
        if yaw_rad is None:
            mask |= _TM_IGNORE_YAW
        msg = self.mav.set_position_target_local_ned_encode(
            _ms(t_s), target_sysid, 1, mavlink2.MAV_FRAME_LOCAL_NED, mask,
            p[1], p[0], -p[2], v[1], v[0], -v[2], 0.0, 0.0, 0.0, yaw_ned, 0.0,
        )
        return self.pack(msg)


def _floats3(v: np.ndarray | Iterable[float]) -> tuple[float, float, float]:
    """A 3-vector (numpy array, list or tuple) as three Python floats."""
    x, y, z = v.tolist() if isinstance(v, np.ndarray) else v
    return float(x), float(y), float(z)


def _cm_s(v_mps: float) -> int:
    """[m/s] -> int16 [cm/s], clamped."""
    return max(-32768, min(32767, round(v_mps * 100.0)))


# ------------------------------------------------------------------------------------------ decoding
@dataclass
class DecodeCounters:
    """What a decoder saw: good messages, CRC rejections, undecodable byte runs, bytes dropped."""

    messages: int = 0
    bad_crc: int = 0
    bad_data: int = 0
    bytes_dropped: int = 0

    def add(self, other: DecodeCounters) -> None:
        self.messages += other.messages
        self.bad_crc += other.bad_crc
        self.bad_data += other.bad_data
        self.bytes_dropped += other.bytes_dropped


class MavlinkDecoder:
    """Bytes -> MAVLink 2 messages with CRC checking, resynchronisation and counters; never raises.

    ``feed`` is the stream interface (an incomplete trailing frame waits for more bytes);
    ``decode_datagram`` parses one datagram on its own (incomplete frames are dropped and counted).
    """

    def __init__(self, dialect: ModuleType | None = None) -> None:
        self.mav = (dialect or mavlink2).MAVLink(None)  # a dialect generated from common.xml + its own messages
        self._counters = DecodeCounters()
        # copies whose parse was shared (MavlinkLink decodes a datagram once for all receivers):
        # counter values of that parse -> number of copies, folded into ``counters`` when read
        self._shared: dict[tuple[int, int, int, int], int] = {}
        self._buf = b""

    @property
    def counters(self) -> DecodeCounters:
        """What this decoder saw, every received copy counted (shared parses included)."""
        if self._shared:
            c = self._counters
            for (messages, bad_crc, bad_data, dropped), n in self._shared.items():
                c.messages += n * messages
                c.bad_crc += n * bad_crc
                c.bad_data += n * bad_data
                c.bytes_dropped += n * dropped
            self._shared.clear()
        return self._counters

    def feed(self, data: bytes) -> list[Any]:
        msgs, rest, c = _scan(self.mav, self._buf + bytes(data), final=False)
        self._buf = rest
        self._counters.add(c)
        return msgs

    def decode_datagram(self, data: bytes) -> list[Any]:
        msgs, _, c = _scan(self.mav, bytes(data), final=True)
        self._counters.add(c)
        return msgs


def _frame_len(buf: bytes, i: int) -> int:
    """Total length of the MAVLink 2 frame that starts at ``buf[i]`` (header present)."""
    n = _HEADER_LEN + buf[i + 1] + 2
    return n + _SIGNATURE_LEN if buf[i + 2] & mavlink2.MAVLINK_IFLAG_SIGNED else n


def _scan(mav: Any, buf: bytes, final: bool) -> tuple[list[Any], bytes, DecodeCounters]:
    """Find and decode every MAVLink 2 frame in ``buf``; returns (messages, unparsed tail, counters)."""
    c = DecodeCounters()
    msgs: list[Any] = []
    i, n = 0, len(buf)
    while i < n:
        j = buf.find(b"\xfd", i)
        if j < 0:
            j = n
        if j > i:  # garbage before the next candidate start
            c.bad_data += 1
            c.bytes_dropped += j - i
            i = j
            continue
        if n - i < _HEADER_LEN + 2 or n - i < _frame_len(buf, i):
            if not final:
                return msgs, buf[i:], c
            c.bad_data += 1  # truncated frame (or a 0xFD inside garbage): drop one byte and rescan
            c.bytes_dropped += 1
            i += 1
            continue
        m = _decode_frame(mav, buf[i : i + _frame_len(buf, i)], c)
        if m is None:
            c.bytes_dropped += 1
            i += 1
        else:
            msgs.append(m)
            c.messages += 1
            i += _frame_len(buf, i)
    return msgs, b"", c


def _decode_frame(mav: Any, frame: bytes, c: DecodeCounters) -> Any | None:
    """pymavlink's decode of one candidate frame; None (and a count) when it is rejected."""
    if frame[2] & ~mavlink2.MAVLINK_IFLAG_SIGNED:
        c.bad_data += 1
        return None
    try:
        m = mav.decode(bytearray(frame))
    except Exception as err:  # noqa: BLE001 - corrupted bytes must never crash the run
        # MAVError of whichever dialect module decoded (each generated module has its own class)
        if type(err).__name__ == "MAVError" and "CRC" in str(getattr(err, "message", err)):
            c.bad_crc += 1
        else:
            c.bad_data += 1
        return None
    if type(m).__name__ in ("MAVLink_unknown", "MAVLink_bad_data"):
        c.bad_data += 1
        return None
    return m


# -------------------------------------------------------------------------------------- observations
@dataclass(frozen=True)
class TrafficReport:
    """What a receiver learned about another aircraft from one datagram (ENU frame).

    ``t_meas_s`` is the sender's measurement time (time_boot_ms); yaw is ENU [rad] (NaN if unknown).
    """

    src: str
    sysid: int
    kind: str  # "uav" (LOCAL_POSITION_NED / GLOBAL_POSITION_INT) or "adsb"
    t_sent_s: float
    t_recv_s: float
    t_meas_s: float
    p_enu: np.ndarray
    v_enu: np.ndarray
    yaw_rad: float


@dataclass(frozen=True)
class Setpoint:
    """A SET_POSITION_TARGET_LOCAL_NED that reached its target (ENU; None where masked out)."""

    dst: str
    t_sent_s: float
    t_recv_s: float
    p_enu: np.ndarray | None
    v_enu: np.ndarray | None
    yaw_rad: float | None


def report_from_messages(
    msgs: Iterable[Any], origin: Origin, src: str, t_sent_s: float, t_recv_s: float
) -> TrafficReport | None:
    """One TrafficReport from a datagram's messages: LOCAL_POSITION_NED preferred, then
    GLOBAL_POSITION_INT, then ADSB_VEHICLE; None when the datagram carries no position."""
    by_type = {m.get_type(): m for m in msgs}
    if (m := by_type.get("LOCAL_POSITION_NED")) is not None:
        p = np.array([m.y, m.x, -m.z])
        v = np.array([m.vy, m.vx, -m.vz])
        yaw = float("nan")
        if (g := by_type.get("GLOBAL_POSITION_INT")) is not None and g.hdg != 0xFFFF:
            yaw = float(wrap_pi(0.5 * np.pi - np.radians(g.hdg / 100.0)))
        return TrafficReport(src, m.get_srcSystem(), "uav", t_sent_s, t_recv_s, m.time_boot_ms / 1e3, p, v, yaw)
    if (m := by_type.get("GLOBAL_POSITION_INT")) is not None:
        p = origin.to_enu(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3)
        v = np.array([m.vy, m.vx, -m.vz]) / 100.0
        yaw = float(wrap_pi(0.5 * np.pi - np.radians(m.hdg / 100.0)))
        return TrafficReport(src, m.get_srcSystem(), "uav", t_sent_s, t_recv_s, m.time_boot_ms / 1e3, p, v, yaw)
    if (m := by_type.get("ADSB_VEHICLE")) is not None:
        p = origin.to_enu(m.lat * 1e-7, m.lon * 1e-7, m.altitude * 1e-3)
        course = 0.5 * np.pi - np.radians(m.heading / 100.0)
        spd = m.hor_velocity / 100.0
        v = np.array([spd * np.cos(course), spd * np.sin(course), m.ver_velocity / 100.0])
        return TrafficReport(
            src, m.ICAO_address, "adsb", t_sent_s, t_recv_s, t_sent_s - m.tslc, p, v, float(wrap_pi(course))
        )
    return None


def setpoint_from_message(m: Any, dst: str, t_sent_s: float, t_recv_s: float) -> Setpoint:
    """SET_POSITION_TARGET_LOCAL_NED -> Setpoint in ENU, honouring its type_mask."""
    p = None if m.type_mask & _TM_IGNORE_POS == _TM_IGNORE_POS else np.array([m.y, m.x, -m.z])
    v = None if m.type_mask & _TM_IGNORE_VEL == _TM_IGNORE_VEL else np.array([m.vy, m.vx, -m.vz])
    yaw = None if m.type_mask & _TM_IGNORE_YAW else float(wrap_pi(0.5 * np.pi - m.yaw))
    return Setpoint(dst, t_sent_s, t_recv_s, p, v, yaw)


@dataclass(frozen=True)
class _ReportFields:
    """The receiver-independent part of a TrafficReport (what the datagram says)."""

    sysid: int
    kind: str
    t_meas_s: float  # ADS-B: NaN, filled from the send time and ``tslc_s``
    p_enu: np.ndarray
    v_enu: np.ndarray
    yaw_rad: float
    tslc_s: float = 0.0

    def received(self, src: str, t_sent_s: float, t_recv_s: float) -> TrafficReport:
        t_meas = t_sent_s - self.tslc_s if self.kind == "adsb" else self.t_meas_s
        return TrafficReport(src, self.sysid, self.kind, t_sent_s, t_recv_s, t_meas, self.p_enu, self.v_enu,
                             self.yaw_rad)


class ReceivedReport(NamedTuple):
    """One receiver's copy of a position report, not yet expanded into a :class:`TrafficReport`
    (a NamedTuple over the shared decode: the cheap form for consumers that keep only the newest
    report per source, see :meth:`MavlinkLink.receive_latest`)."""

    t_meas_s: float  # [s] the sender's measurement time
    fields: _ReportFields  # shared by every receiver of the datagram (arrays read-only)
    src: str
    t_sent_s: float
    t_recv_s: float

    @property
    def p_enu(self) -> np.ndarray:
        return self.fields.p_enu

    @property
    def v_enu(self) -> np.ndarray:
        return self.fields.v_enu

    def report(self) -> TrafficReport:
        """The full :class:`TrafficReport` (what ``receive`` returns for this copy)."""
        return self.fields.received(self.src, self.t_sent_s, self.t_recv_s)


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


@dataclass(frozen=True)
class _Decoded:
    """One datagram decoded and converted once, shared by every receiver of a copy of its bytes."""

    counters: DecodeCounters
    report: _ReportFields | None
    setpoints: tuple[Any, ...]
    counter_key: tuple[int, int, int, int]  # the counters' values (a copy's tally key)
    estimates: tuple[Any, ...] = ()  # TRAFFIC_SEGMENT_ESTIMATE messages (dialect corridor_traffic)

    @staticmethod
    def of(msgs: list[Any], counters: DecodeCounters, origin: Origin) -> _Decoded:
        report = None
        if msgs:
            r = report_from_messages(msgs, origin, "", 0.0, 0.0)
            if r is not None:
                r.p_enu.flags.writeable = False  # shared by every receiver
                r.v_enu.flags.writeable = False
                tslc = next((float(m.tslc) for m in msgs if m.get_type() == "ADSB_VEHICLE"), 0.0)
                report = _ReportFields(r.sysid, r.kind, r.t_meas_s, r.p_enu, r.v_enu, r.yaw_rad, tslc)
        sps = tuple(m for m in msgs if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED")
        key = (counters.messages, counters.bad_crc, counters.bad_data, counters.bytes_dropped)
        est = tuple(m for m in msgs if m.get_type() == "TRAFFIC_SEGMENT_ESTIMATE")
        return _Decoded(counters, report, sps, key, est)


# ---------------------------------------------------------------------------------------------- link
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
        self.dialect = dialect  # None: pymavlink's common; else a generated superset (mavlink_dialect)
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
        self._cache: dict[bytes, _Decoded] = {}
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
        """Deliver, corrupt (if configured), decode; traffic reports and set-points of this instant.

        A broadcast datagram reaches many receivers as copies of the same bytes: each distinct payload
        is decoded and converted once per call (:class:`_Decoded`), and its receivers share the result
        (the counters are still added per received copy, as if every receiver had parsed it)."""
        inbox = Inbox()
        reports = inbox.reports
        for d, decoded in self._received(t_s):
            if decoded.report is not None:
                reports.setdefault(d.dst, []).append(decoded.report.received(d.src, d.t_sent_s, d.t_recv_s))
            if decoded.setpoints:
                self._route_setpoints(inbox, d, decoded)
            if decoded.estimates and d.dst == self.gcs_id:
                self.estimates.extend((d.t_recv_s, d.src, d.t_sent_s, m) for m in decoded.estimates)
        return inbox

    def receive_latest(self, t_s: float, latest: dict[str, dict[str, ReceivedReport]]) -> list[Setpoint]:
        """:meth:`receive` for consumers that keep only the newest report per (receiver, source):
        ``latest[dst][src]`` is replaced by every received report that is not older (sender's
        measurement time) than the one it holds; receivers not in ``latest`` are skipped. The same
        deliveries, decoding and counters as ``receive``, without building a TrafficReport per
        copy (a swarm's broadcasts are N^2 copies per tick). Returns the set-points.

        Without bit errors every copy of a datagram carries the same bytes, so the channel's copies
        are taken message by message (``deliver_batches``): one decode and one measurement time per
        datagram, then per receiver only the counters and the newest-report check. Of several
        reports with the same measurement time the later-delivered one is kept, as in delivery order.
        """
        if self.bit_error_rate > 0.0 or not hasattr(self.channel, "deliver_batches"):
            return self._receive_latest_copies(t_s, latest)
        self._cache.clear()
        decoders, routed = self._decoders, []
        for b in self.channel.deliver_batches(t_s):
            hit = self._decoded(b.payload)
            if hit is None:
                continue
            key, rep, src, t_sent = hit.counter_key, hit.report, b.src, b.t_sent_s
            t_meas = (t_sent - rep.tslc_s if rep.kind == "adsb" else rep.t_meas_s) if rep is not None else 0.0
            for dst, t_recv in zip(b.dst, b.t_recv_s, strict=True):
                dec = decoders.get(dst)
                if dec is None:
                    continue
                dec._shared[key] = dec._shared.get(key, 0) + 1
                if rep is not None and (pend := latest.get(dst)) is not None:
                    old = pend.get(src)
                    if old is None or t_meas > old.t_meas_s or (t_meas == old.t_meas_s and t_recv >= old.t_recv_s):
                        pend[src] = ReceivedReport(t_meas, rep, src, t_sent, t_recv)
                if hit.setpoints:
                    routed.append((t_recv, src, dst, b.seq, t_sent, hit))
                if hit.estimates and dst == self.gcs_id:
                    self.estimates.extend((t_recv, src, t_sent, m) for m in hit.estimates)
        inbox = Inbox()
        for t_recv, src, dst, _, t_sent, hit in sorted(routed, key=lambda r: r[:4]):  # deliver's order
            self._route_setpoints(inbox, _Copy(src, dst, t_sent, t_recv), hit)
        return inbox.setpoints

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
        """:meth:`receive_latest` into a :class:`LatestReports` (made by :meth:`latest_table`): the
        same deliveries, decoding, counters and kept reports, with the copies of a datagram handled
        as arrays (receiver rows, receive times, per-receiver counter tallies) instead of one Python
        step per copy. With bit errors (each copy's bytes may differ) it goes copy by copy."""
        if self.bit_error_rate > 0.0 or not hasattr(self.channel, "deliver_indexed"):
            return self._receive_latest_table_copies(t_s, table)
        self._cache.clear()
        routed, listen = [], self._listening_nodes()
        if self._rx_of_node.size < listen.size:  # nodes the channel learnt after latest_table
            self._rx_of_node = np.r_[self._rx_of_node, np.full(listen.size - self._rx_of_node.size, -1)]
        rx_of = self._rx_of_node
        tally = self._tally
        for b in self.channel.deliver_indexed(t_s):
            hit = self._decoded(b.payload)
            if hit is None:
                continue
            dst = b.dst_idx[listen[b.dst_idx]]
            counts = tally.get(hit.counter_key)
            if counts is None:
                counts = tally[hit.counter_key] = np.zeros(listen.size, dtype=np.int64)
            counts[dst] += 1
            rep, col = hit.report, self._src_col.get(b.src)
            if rep is not None and col is not None:
                rows = rx_of[dst]
                keep = rows >= 0
                t_meas = b.t_sent_s - rep.tslc_s if rep.kind == "adsb" else rep.t_meas_s
                t_recv = b.t_recv_s[listen[b.dst_idx]]
                table.offer(rows[keep], col, t_meas, t_recv[keep], rep.p_enu, rep.v_enu)
            if hit.setpoints or hit.estimates:
                names = self.channel.node_names
                for i, t_recv in zip(b.dst_idx.tolist(), b.t_recv_s.tolist(), strict=True):
                    if hit.setpoints and names[i] in self._decoders:
                        routed.append((t_recv, b.src, names[i], b.seq, b.t_sent_s, hit))
                    if hit.estimates and names[i] == self.gcs_id:  # camera estimates for the ground station
                        self.estimates.extend((t_recv, b.src, b.t_sent_s, m) for m in hit.estimates)
        inbox = Inbox()
        for t_recv, src, dst_id, _, t_sent, hit in sorted(routed, key=lambda r: r[:4]):  # deliver's order
            self._route_setpoints(inbox, _Copy(src, dst_id, t_sent, t_recv), hit)
        return inbox.setpoints

    def _receive_latest_table_copies(self, t_s: float, table: LatestReports) -> list[Setpoint]:
        """:meth:`receive_latest_table` copy by copy (bit errors: each copy decoded on its own)."""
        inbox = Inbox()
        rows = {id: k for k, id in enumerate(table.receivers)}
        for d, decoded in self._received(t_s):
            rep, row, col = decoded.report, rows.get(d.dst), self._src_col.get(d.src)
            if rep is not None and row is not None and col is not None:
                t_meas = d.t_sent_s - rep.tslc_s if rep.kind == "adsb" else rep.t_meas_s
                table.offer(np.array([row]), col, t_meas, np.array([d.t_recv_s]), rep.p_enu, rep.v_enu)
            if decoded.setpoints:
                self._route_setpoints(inbox, d, decoded)
            if decoded.estimates and d.dst == self.gcs_id:
                self.estimates.extend((d.t_recv_s, d.src, d.t_sent_s, m) for m in decoded.estimates)
        return inbox.setpoints

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

    def _receive_latest_copies(self, t_s: float, latest: dict[str, dict[str, ReceivedReport]]) -> list[Setpoint]:
        """:meth:`receive_latest` copy by copy (each copy's bytes may differ: bit errors)."""
        inbox = Inbox()
        for d, decoded in self._received(t_s):
            rep = decoded.report
            if rep is not None and (pend := latest.get(d.dst)) is not None:
                t_meas = d.t_sent_s - rep.tslc_s if rep.kind == "adsb" else rep.t_meas_s
                old = pend.get(d.src)
                if old is None or t_meas >= old.t_meas_s:
                    pend[d.src] = ReceivedReport(t_meas, rep, d.src, d.t_sent_s, d.t_recv_s)
            if decoded.setpoints:
                self._route_setpoints(inbox, d, decoded)
            if decoded.estimates and d.dst == self.gcs_id:
                self.estimates.extend((d.t_recv_s, d.src, d.t_sent_s, m) for m in decoded.estimates)
        return inbox.setpoints

    def _received(self, t_s: float) -> list[tuple[Any, _Decoded]]:
        """Every delivered copy for a listening member with its (shared) decode, in delivery order;
        each copy's counters are added to its receiver's decoder."""
        self._cache.clear()
        decoders, out = self._decoders, []
        corrupt = self.bit_error_rate > 0.0
        for d in self.channel.deliver(t_s):
            dec = decoders.get(d.dst)
            hit = None if dec is None else self._decoded(d.payload, corrupt)
            if hit is None:
                continue
            key = hit.counter_key
            dec._shared[key] = dec._shared.get(key, 0) + 1
            out.append((d, hit))
        return out

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

    def _decoded(self, payload: Any, corrupt: bool = False) -> _Decoded | None:
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

    def _decode_once(self, payload: bytes) -> _Decoded:
        """Datagram decode + conversion (memoised within one receive for copies of the same bytes)."""
        scratch = MavlinkDecoder(self.dialect)
        msgs = scratch.decode_datagram(payload)
        return _Decoded.of(msgs, scratch.counters, self.origin)

    def _route_setpoints(self, inbox: Inbox, d: Any, decoded: _Decoded) -> None:
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
