"""MAVLink 2 encoding: an aircraft's or ground station's state and commands as framed bytes.

:class:`MavlinkEndpoint` is one MAVLink system/component (its ``sysid``) that frames HEARTBEAT,
GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ADSB_VEHICLE and SET_POSITION_TARGET_LOCAL_NED with
pymavlink (dialect ``common`` or a generated superset, MAVLink 2 framing, magic 0xFD, CRC-16/X.25
with CRC_EXTRA) and its own sequence numbers.  Frames: local NED is the scenario's ENU origin (x
north, y east, z down); altitudes in GLOBAL_POSITION_INT / ADSB_VEHICLE are heights above the WGS-84
ellipsoid, ``relative_alt`` is ENU up.  The link that carries the bytes is
:mod:`corridor.vehicles.mavlink.link`; the way back is :mod:`corridor.vehicles.mavlink.decode`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from types import ModuleType
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from corridor.vehicles.geodesy import Origin, heading_from_enu_yaw, wrap_pi

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
