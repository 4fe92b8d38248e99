"""MAVLink 2 decoding: bytes -> messages -> what a receiver learns (ENU), never raising.

Each received datagram is parsed on its own (:meth:`MavlinkDecoder.decode_datagram`): a frame whose
CRC does not match is counted in ``bad_crc`` and the parser resynchronises at the next 0xFD byte;
bytes that are not a frame (garbage, truncated frames, unknown message ids, bad flags) are counted in
``bad_data``.  Nothing corrupted can raise.  One corrupted frame can add more than one count when its
body happens to contain 0xFD bytes (each candidate start is checked, as the C library does).  The
messages become :class:`TrafficReport` (LOCAL_POSITION_NED, GLOBAL_POSITION_INT or ADSB_VEHICLE) and
:class:`Setpoint` (SET_POSITION_TARGET_LOCAL_NED); :class:`Decoded` is one datagram decoded and
converted once, shared by every receiver of a copy of its bytes.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from corridor.vehicles.geodesy import Origin, wrap_pi
from corridor.vehicles.mavlink.encode import _TM_IGNORE_POS, _TM_IGNORE_VEL, _TM_IGNORE_YAW

MAGIC_V2 = mavlink2.PROTOCOL_MARKER_V2  # 0xFD
_HEADER_LEN = mavlink2.HEADER_LEN_V2  # 10 bytes
_SIGNATURE_LEN = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN  # 13 bytes


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
        # copies whose parse was shared (the link decodes a datagram once for all receivers):
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


@dataclass(frozen=True)
class Decoded:
    """One datagram decoded and converted once, shared by every receiver of a copy of its bytes."""

    counters: DecodeCounters
    report: _ReportFields | None
    setpoints: tuple[Any, ...]
    counter_key: tuple[int, int, int, int]  # the counters' values (a copy's tally key)
    estimates: tuple[Any, ...] = ()  # TRAFFIC_SEGMENT_ESTIMATE messages (dialect corridor_traffic)

    @staticmethod
    def of(msgs: list[Any], counters: DecodeCounters, origin: Origin) -> Decoded:
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
        return Decoded(counters, report, sps, key, est)
