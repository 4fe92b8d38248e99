"""The patrol UAVs' cameras as an engine component (``backend.uav_camera``): every ``period_s`` each
camera UAV looks at the ring (``corridor.vehicles.sensors.camera``) and downlinks its per-segment estimates
to the ground station as MAVLink 2 TRAFFIC_SEGMENT_ESTIMATE messages (corridor's dialect) over the
link's channel, where they are delayed, lost and counted like every other datagram.

SENSE phase.  It reads the road vehicles and the UAV rows from the world snapshot (ground truth of
what is below the camera; the camera adds detection misses and noise), the UAVs' roll/pitch through
the air backend's ``attitudes`` seam (the snapshot carries yaw only), and the segment geometry from
the beltway's landmarks.  It keeps, for monitors and the Rerun view, the last frame's observed length
per segment (``observed_m``, max over the UAVs) and each UAV's footprint (centre and radius).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.networks.landmarks import BeltwayLandmarks
from corridor.traffic.networks.segments import RingIndex, RingSegments
from corridor.traffic.sumo.road_spec import road_spec
from corridor.vehicles.air.backend import air_rows
from corridor.vehicles.sensors.camera import CameraParams, observe, optical_axis


class UavCamera(Component):
    """Traffic cameras on the patrol UAVs with a MAVLink downlink (registered as ``uav_camera``)."""

    phase = Phase.SENSE
    needs: ClassVar[dict[str, Need]] = {"air": Need(role="air", name_at="params.backend"),
                                        "link": Need(role="air_link", name_at="params.link")}
    provides: ClassVar[frozenset[str]] = frozenset({"camera"})
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('camera_frames', '1',
               'Camera frames processed.'),
        Metric('camera_estimates_sent', '1',
               'Segment estimates sent on the downlink.'),
        Metric('camera_bytes_sent', 'B',
               'Bytes sent on the downlink.'),
    )
    period_source: ClassVar[str | None] = "params.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        backend: str = "air"
        link: str = "link"  # an air link with ``dialect: corridor_traffic``
        uavs: list[str] | None = None  # camera UAVs; None: every controlled quad with a goal
        period_s: float = Field(2.0, gt=0.0)  # [s] between frames (and downlinks)
        segments_per_link: int = Field(1, ge=1, le=8)  # METANET segments per ring link (the MPC's m)
        camera: CameraParams = Field(default_factory=CameraParams)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.air: Any = None
        self.link: Any = None
        self.frames = 0
        self.messages_sent = 0
        self.bytes_sent = 0
        self.observed_m = np.zeros(0)
        self.footprints: dict[str, tuple[np.ndarray, float]] = {}  # uid -> (centre xy [m], radius [m])

    def setup(self, ctx: RunContext) -> None:
        lm = ctx.snapshot.road.tables.landmarks if ctx.snapshot.road is not None else None
        spec = road_spec(ctx.scenario)
        if not isinstance(lm, BeltwayLandmarks) or spec is None:
            raise ValueError(f"{self.name}: the UAV camera needs the beltway road (a sumo backend with network beltway)")
        if self.link.params.dialect != "corridor_traffic":
            raise ValueError(f"{self.name}: link {self.link.name!r} must use dialect: corridor_traffic")
        self.segments = RingSegments.build(lm, spec.network.params, self.params.segments_per_link)
        self.index = RingIndex(self.segments)
        self.arc_xy, self.arc_seg, self.arc_spacing = self.segments.arc_points(10.0)
        self.observed_m = np.zeros(self.segments.n_seg)
        self.uav_ids = self.params.uavs or [a.id for a in self.air.aircraft
                                            if a.goal_enu is not None and not a.is_piloted]
        self.rng = ctx.rng(f"{self.name}/detections")
        self.mav = self.link.dialect_module()

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        index = air_rows(s)
        if not self.uav_ids or index.get(self.uav_ids[0]) is None:
            return  # before the first air snapshot
        veh = self.index.vehicles(s)
        veh_xy = s.position[veh.rows, :2]
        att = self.air.attitudes()
        seg, p = self.segments, self.params
        observed = np.zeros(seg.n_seg)
        self.footprints = {}
        for uid in self.uav_ids:
            k = index.get(uid)
            if k is None:
                continue
            roll, pitch = att[uid]
            pos = s.position[k]
            axis = optical_axis(roll, pitch, float(s.heading[k]))
            frame = observe(p.camera, pos, axis, self.arc_xy, self.arc_seg, self.arc_spacing, veh_xy, veh.dirn,
                            veh.speed_mps, seg.segment_of, seg.n_seg, seg.n * seg.m, seg.lanes, self.rng)
            self.frames += 1
            observed = np.maximum(observed, frame.observed_m)
            self.footprints[uid] = (frame.footprint_xy, max(pos[2], 0.0) * np.tan(np.radians(p.camera.fov_deg / 2)))
            self._downlink(ctx.t, uid, pos, frame.estimates)
        self.observed_m = observed

    def _downlink(self, t_s: float, uid: str, pos: np.ndarray, estimates: tuple[Any, ...]) -> None:
        if not estimates:
            return
        mav = self.link.link.endpoint(uid).mav
        t_ms = int(round(t_s * 1000.0)) & 0xFFFFFFFF
        msgs = [mav.traffic_segment_estimate_encode(t_ms, e.segment, e.direction, min(e.n_detected, 255),
                                                    e.density, e.density_var, e.speed_mps, e.speed_var,
                                                    e.observed_m)
                for e in estimates]
        self.bytes_sent += self.link.send_to_gcs(t_s, uid, msgs, pos)
        self.messages_sent += len(msgs)

    def rerun_log(self, rec: Any, rr: Any, ctx: RunContext) -> None:
        """The footprints of the last frame as circles on the ground (Rerun layer)."""
        if not self.footprints:
            return
        ang = np.linspace(0.0, 2.0 * np.pi, 48)
        strips = [np.column_stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang), np.full(len(ang), 0.5)])
                  for c, r in self.footprints.values() if np.all(np.isfinite(c))]
        rec.log("world/camera/footprints", rr.LineStrips3D(strips, colors=(250, 220, 60, 255), radii=1.5))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"camera_frames": self.frames, "camera_estimates_sent": self.messages_sent,
                "camera_bytes_sent": self.bytes_sent}
