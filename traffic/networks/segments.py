"""The beltway's METANET segments on the SUMO ring: which vehicle is on which segment, the ground truth
per segment (density, space-mean speed) and the carriageway arcs a camera footprint can cover.

Segment ``i = (dirn * n + k) * m + s`` (the indexing of ``ramp_metering.components.estimate_state``
and of the METANET beltway): direction ``dirn`` (0 = ``ccw``, the outer carriageway; 1 = ``cw``), ring
link ``k`` from the merge of interchange k to the next merge in the travel direction, and sub-segment
``s`` of ``m`` equal angular parts.  A vehicle is on the ring when its lane belongs to one of the
carriageway edges that the landmarks list (``BeltwayLandmarks.ring``; ramps, arterials and junction
interiors are not); its segment follows from its polar angle about the ring centre (the origin).

Ground truth: density [veh/km/lane] = vehicles on the segment / (arc length [km] x lanes), speed =
the arithmetic mean of their speeds (the space-mean speed of the vehicles present at one instant).
Everything is vectorised over the snapshot rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corridor.snapshot import WorldSnapshot
from corridor.traffic.networks.beltway import DIRECTIONS, BeltwayParams, carriageway_arcs
from corridor.traffic.networks.landmarks import BeltwayLandmarks

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class RingSegments:
    """Segment geometry of one beltway (see the module docstring)."""

    n: int  # interchanges
    m: int  # segments per ring link
    lanes: int
    radius_m: tuple[float, float]  # [m] reference radius per direction
    sign: tuple[float, float]  # +1: angle grows in the travel direction
    merge_rad: np.ndarray  # [2, n] merge angle of interchange k per direction
    span_rad: np.ndarray  # [2, n] angular length of link k (merge k to the next merge)
    ring_edges: tuple[frozenset[str], frozenset[str]]

    @staticmethod
    def build(lm: BeltwayLandmarks, p: BeltwayParams, m: int = 1) -> RingSegments:
        radius, sign, merge, span = [], [], [], []
        for d in DIRECTIONS:
            r, sg, angles = carriageway_arcs(p, d)
            a = np.asarray(angles)
            nxt = np.roll(a, -1) if sg > 0 else np.roll(a, 1)
            radius.append(r)
            sign.append(sg)
            merge.append(a)
            span.append(np.mod(sg * (nxt - a), TWO_PI))
        edges = tuple(frozenset(s.edge for s in lm.ring[d]) for d in DIRECTIONS)
        return RingSegments(len(lm.interchanges), int(m), int(lm.lanes), (radius[0], radius[1]), (sign[0], sign[1]),
                            np.array(merge), np.array(span), edges)  # type: ignore[arg-type]

    @property
    def n_seg(self) -> int:
        return 2 * self.n * self.m

    def length_km(self) -> np.ndarray:
        """[n_seg] arc length of every segment [km] (at the carriageway's reference radius)."""
        out = np.empty(self.n_seg)
        for dirn in range(2):
            for k in range(self.n):
                i0 = (dirn * self.n + k) * self.m
                out[i0:i0 + self.m] = self.radius_m[dirn] * self.span_rad[dirn, k] / self.m / 1000.0
        return out

    def segment_of(self, xy: np.ndarray, dirn: np.ndarray) -> np.ndarray:
        """Segment index of points ``xy`` [N, 2] on carriageway ``dirn`` [N] (0/1)."""
        dirn = np.asarray(dirn, dtype=np.int64)
        theta = np.arctan2(xy[:, 1], xy[:, 0])
        sign = np.asarray(self.sign)[dirn]
        # travel-wise offset from every merge of the carriageway: the link is the one with the smallest
        u = np.mod(sign[:, None] * (theta[:, None] - self.merge_rad[dirn]), TWO_PI)  # [N, n]
        k = np.argmin(u, axis=1)
        frac = u[np.arange(len(k)), k] / self.span_rad[dirn, k]
        s = np.minimum((frac * self.m).astype(np.int64), self.m - 1)
        return (dirn * self.n + k) * self.m + s

    def lane_directions(self, lane_names: list[str]) -> np.ndarray:
        """Per lane code: 0 / 1 for a lane of the ccw / cw carriageway, -1 otherwise."""
        out = np.full(len(lane_names), -1, dtype=np.int64)
        for code, name in enumerate(lane_names):
            edge = name.rsplit("_", 1)[0]
            for dirn in range(2):
                if edge in self.ring_edges[dirn]:
                    out[code] = dirn
        return out

    def arc_points(self, step_m: float = 10.0) -> tuple[np.ndarray, np.ndarray, float]:
        """Points every ~``step_m`` along both carriageways: (xy [P, 2], segment [P], spacing [m] per
        point, the same on both)."""
        pts, seg = [], []
        spacing = step_m
        for dirn in range(2):
            r = self.radius_m[dirn]
            count = int(np.ceil(TWO_PI * r / step_m))
            theta = (np.arange(count) + 0.5) * TWO_PI / count
            xy = np.column_stack([r * np.cos(theta), r * np.sin(theta)])
            pts.append(xy)
            seg.append(self.segment_of(xy, np.full(count, dirn)))
            spacing = TWO_PI * r / count
        return np.vstack(pts), np.concatenate(seg), spacing


@dataclass(frozen=True)
class RingVehicles:
    """The road vehicles of a snapshot that are on the ring: rows, direction, segment, speed."""

    rows: np.ndarray  # snapshot rows
    dirn: np.ndarray
    segment: np.ndarray
    speed_mps: np.ndarray


class RingIndex:
    """Maps a snapshot's road rows to ring segments (lane codes cached as the lane table grows)."""

    def __init__(self, seg: RingSegments) -> None:
        self.seg = seg
        self._lane_dir = np.zeros(0, dtype=np.int64)

    def vehicles(self, s: WorldSnapshot) -> RingVehicles:
        road = s.road
        if road is None or len(road) == 0:
            z = np.zeros(0, dtype=np.int64)
            return RingVehicles(z, z, z, np.zeros(0))
        names = road.tables.lane_names
        if len(self._lane_dir) != len(names):
            self._lane_dir = self.seg.lane_directions(names)
        dirn = self._lane_dir[road.lane]
        on = dirn >= 0
        rows = np.arange(road.sl.start, road.sl.stop)[on]
        d = dirn[on]
        seg = self.seg.segment_of(s.position[rows, :2], d)
        speed = np.linalg.norm(s.velocity[rows, :2], axis=1)
        return RingVehicles(rows, d, seg, speed)

    def truth(self, s: WorldSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth per segment: density [veh/km/lane], space-mean speed [km/h] (nan: empty)."""
        v = self.vehicles(s)
        n_seg = self.seg.n_seg
        count = np.bincount(v.segment, minlength=n_seg).astype(float)
        speed_sum = np.bincount(v.segment, weights=v.speed_mps, minlength=n_seg)
        rho = count / (self.seg.length_km() * self.seg.lanes)
        with np.errstate(invalid="ignore", divide="ignore"):
            speed = np.where(count > 0, 3.6 * speed_sum / np.maximum(count, 1.0), np.nan)
        return rho, speed
