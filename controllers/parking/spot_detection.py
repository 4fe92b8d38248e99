"""Parking-spot detection from side-looking range sensors while driving past a row of parked cars.

The row is a reference line (``origin``, unit ``direction``: the kerb or the bays' entry line) with the
bays on its ``side`` (+1 left of the direction, -1 right).  Every echo (or its absence) of a sensor
whose beam points into the row (within ``max_squint_rad`` of the row's normal) and that stands close
enough to the line to see ``probe_m`` into the row is one observation of the cell (``cell_m`` long,
along the line) the sensor is abreast of: *occupied* if the echo lies less than ``probe_m`` beyond
the line (something stands in the row), *free* otherwise (no echo, or an echo deeper in the row).
Noise rejection is by evidence, not by single readings:

* a cell is occupied when at least ``occupied_ratio`` of its observations say so (a spurious echo in
  a gap, probability ``p``, gives a ratio ~ ``p``; a dropout on a car, probability ``q``, still leaves
  ``1 - q``);
* occupied runs shorter than ``min_object_m`` are cleared (isolated ghosts), free runs shorter than
  ``min_gap_m`` are filled (dropouts between two echoes of one car);
* unobserved cells are never free: a slot is a run of *observed* free cells of at least the
  required length: ``parallel_length_m`` (along the row) or ``perpendicular_width_m``.

``true_slots`` computes the same intervals from exact geometry (parked-car polygons), and
``match_slots`` scores detections against them (precision / recall; a detection matches a true slot
when their intervals overlap by at least ``min_iou``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DetectorParams:
    cell_m: float = 0.2  # [m]
    probe_m: float = 2.0  # [m] an echo less than this beyond the line is something in the row
    max_squint_rad: float = 0.5  # [rad] beams further from the row's normal are not used
    occupied_ratio: float = 0.5
    min_object_m: float = 0.5  # [m]
    min_gap_m: float = 0.6  # [m]
    parallel_length_m: float = 6.0  # [m] free length needed along the row (parallel parking)
    perpendicular_width_m: float = 2.8  # [m] free width needed (perpendicular parking)


@dataclass(frozen=True)
class Slot:
    s0_m: float  # [m] along the row's line
    s1_m: float

    @property
    def length_m(self) -> float:
        return self.s1_m - self.s0_m

    @property
    def centre_m(self) -> float:
        return 0.5 * (self.s0_m + self.s1_m)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of a boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


class SlotDetector:
    """Accumulates observations along one row; ``slots(kind)`` gives the free slots seen so far."""

    def __init__(self, origin: np.ndarray, direction: np.ndarray, side: int, length_m: float,
                 params: DetectorParams | None = None) -> None:
        self.p = params or DetectorParams()
        self.origin = np.asarray(origin, dtype=float)
        self.direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
        self.side = int(side)
        self.normal = self.side * np.array([-self.direction[1], self.direction[0]])  # into the row
        n = int(np.ceil(length_m / self.p.cell_m))
        self.n_obs = np.zeros(n, dtype=np.int64)
        self.n_occ = np.zeros(n, dtype=np.int64)

    def add(self, origin: np.ndarray, axis: np.ndarray, range_m: np.ndarray, max_range_m: float) -> None:
        """Observations of a scan (sensor origins (n, 2), beam axes (n, 2), ranges (n,), nan = no echo);
        beams not pointing into the row, too far from it or off the row's extent are ignored."""
        origin, axis, r = np.asarray(origin, float), np.asarray(axis, float), np.asarray(range_m, float)
        depth = -(origin - self.origin) @ self.normal  # [m] sensor's distance before the line
        gate = depth + self.p.probe_m  # [m] range to probe_m beyond the line
        s = (origin - self.origin) @ self.direction
        k = np.floor(s / self.p.cell_m).astype(np.int64)
        keep = ((axis @ self.normal) >= np.cos(self.p.max_squint_rad)) & (depth >= -0.5) & (gate <= max_range_m)
        keep &= (k >= 0) & (k < len(self.n_obs))
        occ = np.isfinite(r) & (r < gate)
        np.add.at(self.n_obs, k[keep], 1)
        np.add.at(self.n_occ, k[keep], occ[keep].astype(np.int64))

    def occupancy(self) -> tuple[np.ndarray, np.ndarray]:
        """(observed, occupied) per cell after the run filters."""
        seen = self.n_obs > 0
        occ = seen & (self.n_occ >= self.p.occupied_ratio * np.maximum(self.n_obs, 1))
        c = self.p.cell_m
        for a, b in _runs(occ):
            if (b - a) * c < self.p.min_object_m:
                occ[a:b] = False
        free = seen & ~occ
        for a, b in _runs(free):
            if (b - a) * c < self.p.min_gap_m and a > 0 and b < len(occ) and occ[a - 1] and occ[b]:
                occ[a:b] = True
        return seen, occ

    def slots(self, kind: str = "perpendicular") -> list[Slot]:
        need = self.p.parallel_length_m if kind == "parallel" else self.p.perpendicular_width_m
        seen, occ = self.occupancy()
        c = self.p.cell_m
        return [Slot(a * c, b * c) for a, b in _runs(seen & ~occ) if (b - a) * c >= need]

    def observed_extent(self) -> tuple[float, float] | None:
        """[s0, s1] [m] of the observed cells (None: nothing observed)."""
        k = np.flatnonzero(self.n_obs > 0)
        return None if not len(k) else (float(k[0] * self.p.cell_m), float((k[-1] + 1) * self.p.cell_m))


def true_slots(polygons: np.ndarray, origin: np.ndarray, direction: np.ndarray, side: int,
               band_m: tuple[float, float], extent: tuple[float, float], need_m: float) -> list[Slot]:
    """Free intervals of at least ``need_m`` within ``extent`` along the line, between the polygons
    (m, k, 2) that reach into the row band (``band_m``: distances from the line on ``side``)."""
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    normal = side * np.array([-direction[1], direction[0]])
    occ: list[tuple[float, float]] = []
    for poly in np.asarray(polygons, dtype=float).reshape(-1, np.shape(polygons)[-2] if len(polygons) else 1, 2):
        rel = poly - origin
        s, d = rel @ direction, rel @ normal
        if d.max() >= band_m[0] and d.min() <= band_m[1]:
            occ.append((float(s.min()), float(s.max())))
    occ.sort()
    slots, cur = [], extent[0]
    for a, b in occ + [(extent[1], extent[1])]:
        a, b = min(max(a, extent[0]), extent[1]), min(max(b, extent[0]), extent[1])
        if a - cur >= need_m:
            slots.append(Slot(cur, a))
        cur = max(cur, b)
    return slots


def match_slots(found: list[Slot], truth: list[Slot], min_iou: float = 0.5) -> tuple[int, int, int]:
    """(true positives, detections, true slots); each true slot matches at most one detection."""
    used: set[int] = set()
    tp = 0
    for f in found:
        for j, g in enumerate(truth):
            if j in used:
                continue
            inter = min(f.s1_m, g.s1_m) - max(f.s0_m, g.s0_m)
            union = max(f.s1_m, g.s1_m) - min(f.s0_m, g.s0_m)
            if inter > 0 and inter / union >= min_iou:
                used.add(j)
                tp += 1
                break
    return tp, len(found), len(truth)
