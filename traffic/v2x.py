"""V2X cooperative awareness: the CAM-like state message and its periodic generation.

Connected vehicles broadcast a small state message at ``rate_hz`` (ETSI CAM-like: who, when, where,
how fast, which lane, and — for cooperative merging — the intended merge time).  Generation is
vectorised: the caller passes struct-of-arrays state (as read from the world snapshot) and gets the
list of messages due at this tick; transport is ``corridor.channel.Channel``.

Each vehicle's first message is sent at a random phase inside one period (when an rng is given), so
a fleet does not transmit in lock-step — real CAM generation is not synchronised either.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from corridor.channel import Channel, Delivery

_DUE_EPS_S = 1e-9  # [s] tolerance of the period comparison against float round-off


@dataclass(frozen=True, slots=True)
class CamMessage:
    """One cooperative-awareness message (position in the scenario's local ENU frame)."""

    sender_id: str
    t_sent_s: float  # [s] generation time
    x_m: float  # [m] east
    y_m: float  # [m] north
    speed_mps: float  # [m/s]
    accel_mps2: float  # [m/s²] longitudinal
    heading_rad: float  # [rad] ENU yaw, counter-clockwise from east
    lane_index: int
    merge_time_s: float | None = None  # [s] intended (assigned) merge-point crossing time
    road: str | None = None  # "main" | "ramp" (map-matched edge class), if known
    dist_to_merge_m: float | None = None  # [m] remaining distance to the merge point, if known

    @property
    def position_m(self) -> np.ndarray:
        """(x, y) [m]."""
        return np.array([self.x_m, self.y_m])


class CamGenerator:
    """Decides which vehicles are due to send and builds their messages (struct-of-arrays in)."""

    def __init__(self, rate_hz: float = 10.0, rng: np.random.Generator | None = None) -> None:
        if rate_hz <= 0:
            raise ValueError("rate_hz must be > 0")
        self.period_s = 1.0 / rate_hz  # [s]
        self._rng = rng
        self._next_s: dict[str, float] = {}  # [s] next generation time per vehicle

    def due(self, t_s: float, ids: Sequence[str]) -> np.ndarray:
        """Boolean mask of the vehicles whose message is due at ``t_s`` (advances their schedule)."""
        mask = np.zeros(len(ids), dtype=bool)
        for k, vid in enumerate(ids):
            nxt = self._next_s.get(vid)
            if nxt is None:
                phase = self._rng.uniform(0.0, self.period_s) if self._rng is not None else 0.0
                nxt = self._next_s[vid] = t_s + phase
            if t_s + _DUE_EPS_S >= nxt:
                mask[k] = True
                # next slot on the period grid, skipping missed slots (coarse ticks)
                n_missed = math.floor((t_s + _DUE_EPS_S - nxt) / self.period_s)  # np.floor's value
                self._next_s[vid] = nxt + (n_missed + 1.0) * self.period_s
        return mask

    def forget(self, ids: Iterable[str]) -> None:
        """Drop the schedule of vehicles that left the scenario."""
        for vid in ids:
            self._next_s.pop(vid, None)

    def build(
        self,
        t_s: float,
        ids: Sequence[str],
        pos_m: np.ndarray,
        speed_mps: np.ndarray,
        accel_mps2: np.ndarray,
        heading_rad: np.ndarray,
        lane_index: np.ndarray,
        merge_time_s: np.ndarray | None = None,
        road: Sequence[str] | None = None,
        dist_to_merge_m: np.ndarray | None = None,
    ) -> list[CamMessage]:
        """Messages of the vehicles due at ``t_s``; ``pos_m`` is [N, 2|3], NaN merge time = none."""
        idx = np.flatnonzero(self.due(t_s, ids))
        return [
            CamMessage(
                sender_id=ids[k],
                t_sent_s=float(t_s),
                x_m=float(pos_m[k, 0]),
                y_m=float(pos_m[k, 1]),
                speed_mps=float(speed_mps[k]),
                accel_mps2=float(accel_mps2[k]),
                heading_rad=float(heading_rad[k]),
                lane_index=int(lane_index[k]),
                merge_time_s=_opt(merge_time_s, k),
                road=road[k] if road is not None else None,
                dist_to_merge_m=_opt(dist_to_merge_m, k),
            )
            for k in idx
        ]


def broadcast(channel: Channel, messages: Iterable[CamMessage]) -> int:
    """Send every message from its sender's position; returns the copies put in flight."""
    return sum(channel.send(m.t_sent_s, m.sender_id, m, src_pos=m.position_m) for m in messages)


def latest_by_sender(deliveries: Iterable[Delivery]) -> dict[str, CamMessage]:
    """Newest CAM per sender among ``deliveries`` (other payload types are ignored)."""
    latest: dict[str, CamMessage] = {}
    for d in deliveries:
        m = d.payload
        if isinstance(m, CamMessage):
            cur = latest.get(m.sender_id)
            if cur is None or m.t_sent_s > cur.t_sent_s:
                latest[m.sender_id] = m
    return latest


def _opt(values: np.ndarray | None, k: int) -> float | None:
    if values is None:
        return None
    v = float(values[k])
    return None if np.isnan(v) else v
