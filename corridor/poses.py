"""Lazily derived geometry of snapshot rows.

A backend whose library reports a vehicle by a reference point on its heading axis (SUMO: the front
bumper), a compass bearing and a speed along the heading hands those columns to the snapshot as
``PlanarPoses``; the snapshot's ``position`` (centre), ``velocity`` and ``heading`` are derived on
first access and cached (read-only), so a tick whose consumers read only the road frame (lane codes,
positions along the lane) never pays the ~15 numpy calls of the geometry.

Consumers that hold many ticks (the road monitors' blocks of ticks) derive the geometry of all of
them in one pass (``fill_many``).  The arithmetic is elementwise, so a row's values do not depend on
how the rows are cut: every consumer gets the identical arrays, whichever path filled them
(``tests/corridor/test_kernel_poses.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Geometry = tuple[np.ndarray, np.ndarray, np.ndarray]  # position (N, 3) [m], velocity (N, 3) [m/s], heading (N,) [rad]


def planar_geometry(ref_xy: np.ndarray, bearing_deg: np.ndarray, speed_mps: np.ndarray,
                    back_m: np.ndarray) -> Geometry:
    """Centre, velocity and ENU yaw of rows on the ground plane (z = 0).

    ``ref_xy`` (N, 2) [m]: a point on each row's heading axis, ``back_m`` (N, 1) [m] ahead of its
    centre (a front bumper: half the length); ``bearing_deg`` (N,): heading in degrees clockwise from
    north; ``speed_mps`` (N,): speed along the heading.  Yaw is counter-clockwise from east [rad].
    """
    n = len(bearing_deg)
    yaw = np.radians(90.0 - bearing_deg)
    cs = np.empty((n, 2))
    cs[:, 0], cs[:, 1] = np.cos(yaw), np.sin(yaw)
    pos = np.zeros((n, 3))
    pos[:, :2] = ref_xy - back_m * cs
    vel = np.zeros((n, 3))
    vel[:, :2] = speed_mps[:, None] * cs
    for a in (pos, vel, yaw):
        a.flags.writeable = False
    return pos, vel, yaw


class PlanarPoses:
    """The raw pose columns of one tick's rows (see ``planar_geometry``).

    ``geometry()`` derives and caches the snapshot's position, velocity and heading.
    """

    __slots__ = ("ref_xy", "bearing_deg", "speed_mps", "back_m", "_geometry")

    def __init__(self, ref_xy: np.ndarray, bearing_deg: np.ndarray, speed_mps: np.ndarray,
                 back_m: np.ndarray) -> None:
        self.ref_xy, self.bearing_deg, self.speed_mps, self.back_m = ref_xy, bearing_deg, speed_mps, back_m
        self._geometry: Geometry | None = None

    def __len__(self) -> int:
        return int(self.bearing_deg.shape[0])

    @property
    def filled(self) -> bool:
        """Whether the geometry has been derived already."""
        return self._geometry is not None

    def geometry(self) -> Geometry:
        """Position [m], velocity [m/s] and heading [rad] of the rows, derived on first call."""
        if self._geometry is None:
            self._geometry = planar_geometry(self.ref_xy, self.bearing_deg, self.speed_mps, self.back_m)
        return self._geometry

    def pending(self) -> list[PlanarPoses]:
        """The pose sets still to derive: this one, or none."""
        return [] if self.filled else [self]

    @staticmethod
    def fill_many(poses: Sequence[PlanarPoses]) -> Geometry | None:
        """Derive the geometry of every unfilled one in one numpy pass.

        The values are identical (the arithmetic is elementwise); each keeps read-only views of the
        joint arrays, which are returned when every one of ``poses`` was unfilled (else None).
        """
        todo = [p for p in poses if p._geometry is None]
        if len(todo) < 2:
            for p in todo:
                p.geometry()
            return todo[0]._geometry if len(todo) == len(poses) == 1 else None
        pos, vel, yaw = planar_geometry(np.concatenate([p.ref_xy for p in todo]),
                                        np.concatenate([p.bearing_deg for p in todo]),
                                        np.concatenate([p.speed_mps for p in todo]),
                                        np.concatenate([p.back_m for p in todo]))
        k = 0
        for p in todo:
            n = len(p)
            p._geometry = (pos[k:k + n], vel[k:k + n], yaw[k:k + n])
            k += n
        return (pos, vel, yaw) if len(todo) == len(poses) else None


class ConcatGeometry:
    """The geometry of snapshot parts joined row-wise (``WorldSnapshot.from_parts``), derived when first read.

    ``parts`` are the parts' geometries (arrays, or lazy sources with ``geometry()``).
    """

    __slots__ = ("parts", "_geometry")

    def __init__(self, parts: Sequence[Geometry | PlanarPoses | ConcatGeometry]) -> None:
        self.parts = parts
        self._geometry: Geometry | None = None

    @property
    def filled(self) -> bool:
        """Whether the joined geometry has been derived already."""
        return self._geometry is not None

    def pending(self) -> list[PlanarPoses]:
        """The parts' pose sets still to derive."""
        if self._geometry is not None:
            return []
        return [q for p in self.parts if not isinstance(p, tuple) for q in p.pending()]

    def geometry(self) -> Geometry:
        """Position [m], velocity [m/s] and heading [rad] of all parts' rows, joined on first call."""
        if self._geometry is None:
            geos = [p if isinstance(p, tuple) else p.geometry() for p in self.parts]
            joined = tuple(np.concatenate([g[i] for g in geos]) for i in range(3))
            for a in joined:
                a.flags.writeable = False
            self._geometry = joined  # type: ignore[assignment]
        return self._geometry  # type: ignore[return-value]
