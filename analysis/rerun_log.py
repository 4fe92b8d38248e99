"""Rerun recording of one run: lanes as line strips, every entity of a frame as one batched Boxes3D
coloured by role, trails of aircraft and of controlled vehicles, key scalars as time series, mode
transitions and collisions as text log entries, and a default blueprint (3D view + time series + log).
Also drawn, when present: the outlines of the road's landmarks (``landmarks.outlines()``, e.g. a
parking lot's bays and walls), the polyline an event carries (``data["polyline"]``: a planned path, at
``world/events/<source>/<kind>``), and whatever a component offers through ``overlays()`` (name ->
``("lines", [(k, 2)...])`` or ``("points", (n, 2))``: e.g. sensor beams and echoes).

A recorder only reads the snapshot, signals and events: recording never changes a trajectory.
A component may add its own layer by defining ``rerun_log(rec, rr, ctx)`` (read-only; called at each
frame, e.g. the UAV cameras' footprints on the road, the ramp meters' rates).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from corridor.engine import Component, Phase, RunContext
from corridor.snapshot import Kind, Role

ROLE_COLORS = {  # RGBA
    int(Role.MAINLINE): (70, 130, 220, 255),
    int(Role.RAMP): (240, 160, 40, 255),
    int(Role.CONTROLLED): (40, 190, 90, 255),
    int(Role.OTHER): (160, 160, 160, 255),
}
GRID_STEP_M = 100.0  # [m] ground grid spacing
GRID_MIN_HALF_M = 1000.0  # [m] the grid reaches at least this far from the origin
MARKER_UI_PT = 6.0  # [UI points] radius of the aircraft / UAV markers on screen
KIND_COLORS = {int(Kind.UAV): (200, 60, 200, 255), int(Kind.AIRCRAFT): (220, 40, 40, 255)}


def blueprint() -> Any:
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="world"),
            rrb.Vertical(rrb.TimeSeriesView(origin="metrics", name="metrics"),
                         rrb.TextLogView(origin="events", name="events")),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunRecorder(Component):
    phase = Phase.RECORD
    period_source: ClassVar[str | None] = "rerun_period_s"

    def __init__(self, name: str, scenario: Any, path: str | Path) -> None:
        super().__init__(name)
        # [s] the scenario's outputs.rerun_period on the dt grid (at least one tick)
        self.rerun_period_s = max(scenario.dt, round(scenario.outputs.rerun_period / scenario.dt) * scenario.dt)
        self.path = Path(path)
        self._events_seen = 0
        self._signals_seen: dict[str, int] = {}
        self._trails: dict[str, list[np.ndarray]] = {}
        self._ctx: RunContext | None = None

    def setup(self, ctx: RunContext) -> None:
        import rerun as rr

        self.rr = rr
        self._ctx = ctx  # read again in close(), after the other components' finish()
        self.rec = rr.RecordingStream("corridor", recording_id=f"{ctx.scenario.name}-{ctx.run_seed}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(self.path, default_blueprint=blueprint())
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for b in ctx.backends():
            shapes = getattr(getattr(b, "net", None), "lane_shapes", None)
            if shapes:
                strips = [np.column_stack([s, np.zeros(len(s))]) for s in shapes.values()]
                self.rec.log("world/road/lanes", rr.LineStrips3D(strips, colors=(120, 120, 120, 255), radii=0.08),
                             static=True)

        self._log_ground(ctx)
        marks = ctx.snapshot.road.tables.landmarks if ctx.snapshot.road is not None else None
        outlines = getattr(marks, "outlines", None)
        if callable(outlines):
            for name, polys in outlines().items():
                strips = [np.column_stack([np.vstack([q, q[:1]]), np.zeros(len(q) + 1)]) for q in polys]
                self.rec.log(f"world/landmarks/{name}", rr.LineStrips3D(strips, radii=0.06), static=True)

    def _log_ground(self, ctx: RunContext) -> None:
        """A grid on the ground (z = 0) centred on the scenario's origin: GRID_STEP_M lines over the
        road's extent (at least GRID_MIN_HALF_M either way), so a scene is never afloat in black."""
        half = GRID_MIN_HALF_M
        for b in ctx.backends():
            shapes = getattr(getattr(b, "net", None), "lane_shapes", None)
            if shapes:
                pts = np.vstack([np.asarray(q, float)[:, :2] for q in shapes.values()])
                half = max(half, float(np.abs(pts).max()))
        half = GRID_STEP_M * np.ceil(half / GRID_STEP_M)
        ticks = np.arange(-half, half + GRID_STEP_M / 2, GRID_STEP_M)
        strips = [np.array([[x, -half, 0.0], [x, half, 0.0]]) for x in ticks]
        strips += [np.array([[-half, y, 0.0], [half, y, 0.0]]) for y in ticks]
        self.rec.log("world/ground", self.rr.LineStrips3D(strips, colors=(70, 70, 70, 255), radii=0.3), static=True)
        self.rec.log("world/origin", self.rr.Arrows3D(origins=np.zeros((3, 3)), vectors=np.eye(3) * GRID_STEP_M,
                                                      colors=[(220, 60, 60), (60, 200, 60), (60, 60, 220)],
                                                      labels=["east", "north", "up"]), static=True)

    def _log_air_markers(self, s: Any, centers: np.ndarray, colors: np.ndarray) -> None:
        """Aircraft and UAVs as points of a fixed size on screen (MARKER_UI_PT), beside their true-size
        boxes, so that a 1 m UAV stays visible in a km-wide scene."""
        air = np.flatnonzero((s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT))
        if len(air):
            rr = self.rr
            self.rec.log("world/air_markers", rr.Points3D(centers[air], colors=colors[air],
                                                          radii=rr.components.Radius.ui_points(MARKER_UI_PT),
                                                          labels=[str(i) for i in s.ids[air]]))

    def _log_overlays(self, ctx: RunContext) -> None:
        rr = self.rr
        for c in ctx.components.values():
            fn = getattr(c, "overlays", None)
            if not callable(fn):
                continue
            for name, (kind, data) in fn().items():
                path = f"world/overlays/{c.name}/{name}"
                if kind == "lines":
                    self.rec.log(path, rr.LineStrips3D([np.column_stack([q, np.full(len(q), 0.5)]) for q in data],
                                                       radii=0.03))
                elif kind == "points":
                    pts = np.asarray(data).reshape(-1, 2)
                    self.rec.log(path, rr.Points3D(np.column_stack([pts, np.full(len(pts), 0.5)]), radii=0.08))

    def tick(self, ctx: RunContext) -> None:
        rr, rec, s = self.rr, self.rec, ctx.snapshot
        rec.set_time("sim_time", duration=ctx.t)
        if len(s):
            half = 0.5 * s.size
            half[:, 2] = np.maximum(half[:, 2], 0.1)
            centers = s.position.copy()
            centers[:, 2] += half[:, 2]
            colors = np.array([KIND_COLORS.get(int(k), ROLE_COLORS.get(int(r), ROLE_COLORS[3]))
                               for k, r in zip(s.kind, s.role)], dtype=np.uint8)
            quats = np.column_stack([np.zeros((len(s), 2)), np.sin(s.heading / 2), np.cos(s.heading / 2)])
            rec.log("world/entities", rr.Boxes3D(centers=centers, half_sizes=half, quaternions=quats,
                                                 colors=colors, labels=[str(i) for i in s.ids],
                                                 show_labels=False))
            self._log_air_markers(s, centers, colors)
            self._log_trails(s)
        self._log_overlays(ctx)
        for c in ctx.components.values():
            hook = getattr(c, "rerun_log", None)
            if hook is not None and c is not self:
                hook(rec, rr, ctx)
        self._log_new_signals(ctx)
        self._log_new_events(ctx)

    def _log_new_signals(self, ctx: RunContext) -> None:
        """Every signal sample recorded since the last call (monitors that work in blocks of ticks
        record a block's samples at once, with their own times)."""
        rr, rec = self.rr, self.rec
        for name in ctx.signals.names():
            t, v = ctx.signals.get(name)
            k = self._signals_seen.get(name, 0)
            for ti, vi in zip(t[k:], v[k:]):
                if not math.isfinite(vi):  # no value at this tick (min_ttc: no closing pair, +inf)
                    continue
                rec.set_time("sim_time", duration=float(ti))
                rec.log(f"metrics/{name}", rr.Scalars(float(vi)))
            self._signals_seen[name] = len(t)

    def _log_new_events(self, ctx: RunContext) -> None:
        rr, rec = self.rr, self.rec
        for ev in ctx.events.events[self._events_seen:]:
            rec.set_time("sim_time", duration=ev.t)
            level = "ERROR" if ev.kind == "collision" else ("WARN" if ev.kind in ("fallback", "teleport") else "INFO")
            rec.log("events", rr.TextLog(f"[{ev.kind}] {ev.source}: {ev.message}", level=level))
            line = ev.data.get("polyline")
            if line is not None and len(line) > 1:
                xy = np.asarray(line, dtype=float)
                rec.log(f"world/events/{ev.source}/{ev.kind}",
                        rr.LineStrips3D([np.column_stack([xy, np.full(len(xy), 0.05)])], radii=0.05))
        self._events_seen = len(ctx.events.events)

    def _log_trails(self, s: Any) -> None:
        air = np.nonzero((s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT) | (s.role == Role.CONTROLLED))[0]
        if not len(air):
            return
        for k in air:
            trail = self._trails.setdefault(str(s.ids[k]), [])
            trail.append(s.position[k].copy())
            del trail[:-300]
        strips = [np.array(t) for t in self._trails.values() if len(t) > 1]
        if strips:
            self.rec.log("world/trails", self.rr.LineStrips3D(strips, radii=0.15))

    def close(self) -> None:
        """After every component's ``finish`` (the engine closes last): log what they recorded since
        the last frame (a block monitor's last partial block, the specs' signals), then flush."""
        if hasattr(self, "rec"):
            if self._ctx is not None:
                self._log_new_signals(self._ctx)
                self._log_new_events(self._ctx)
            self.rec.flush()
            self.rec.disconnect()
