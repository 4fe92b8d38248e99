"""Parking measurements from the snapshot: pose error at the goal, clearance, manoeuvre time, direction
changes.  A DETECT-phase monitor (``parking``) that reads only the snapshot: the ego's row and the
lot's typed landmarks (a ``ParkingLot`` in the road frame: the goal bay's centre and heading) or, where
the road has no given goal (a street where the controller picks a slot), the last ``goal`` event (box
centre ``x``, ``y`` and ``heading`` the controller announced before manoeuvring), so any controller in
the ego's place is judged the same way.

* ``success``: the ego's box centre within ``pos_tol_m`` of the goal bay's centre, its heading within
  ``heading_tol_rad`` of the bay's (either direction with ``either_direction``), standing
  (``|v| < stop_mps``) at the end of the run, and no collision (the collision monitor's count is not
  visible here: ``success`` is pose-based; the report shows both);
* ``pos_err_m`` / ``heading_err_rad``: the final pose error;
* ``min_clearance_m``: the smallest distance of the ego's box to any other entity's box over the run;
* ``manoeuvre_time_s``: from the first motion (``|v| > stop_mps``; on a street: the announced goal) to
  the last motion;
* ``slot_precision`` / ``slot_recall``: the slots a controller reported (events of kind ``slots``: per
  row its line, the observed extent and the detected intervals) against the true free intervals
  between the parked cars of the first snapshot (``spot_detection.true_slots``, same extent);
* ``direction_changes``: sign changes of the ego's signed speed (counted when ``|v| > direction_mps``,
  so the creeping of a final correction is not counted).

Signals: ``clearance`` [m], ``speed`` [m/s] (signed, from the displacement along the heading) and
``pos_err`` [m] each period.  At the end it writes ``parking/lot-<run_id>.json`` for the report's lot
figure: the lot's outlines (``landmarks.outlines()``), the parked cars' boxes, the goal pose, every
planned path the run's events carried (``data["polyline"]`` of ``plan`` events) and the driven path
(the ego's box centre each period).
"""

from __future__ import annotations

import json
import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.parking.clearance import box_polygons, clearances
from corridor.controllers.parking.spot_detection import Slot, match_slots, true_slots
from corridor.engine import Component, Metric, Phase, RunContext
from corridor.snapshot import Kind

LOT_FILE = "parking/lot.json"  # per run: parking/lot-<run_id>.json


class ParkingMonitor(Component):
    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('success', '1',
               "1 if the ego stopped within the monitor's position and heading tolerance of the bay pose."),
        Metric('pos_err_m', 'm',
               "Final distance of the ego's reference point from the goal pose."),
        Metric('heading_err_rad', 'rad',
               'Final absolute heading error to the goal pose.'),
        Metric('min_clearance_m', 'm',
               "Smallest distance between the ego's footprint and any obstacle."),
        Metric('manoeuvre_time_s', 's',
               'Time from the first move (or the slot choice) to the last move.'),
        Metric('direction_changes', '1',
               'Forward/reverse switches during the manoeuvre.'),
        Metric('slot_precision', '1',
               'Share of the detected free slots that are real free slots.'),
        Metric('slot_recall', '1',
               'Share of the real free slots that were detected.'),
        Metric('slots_detected', '1',
               "Free slots the ego's sensors detected."),
        Metric('slots_true', '1',
               'Free slots in the scene.'),
    )
    period_source: ClassVar[str | None] = "p.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        ego: str = "ego"
        period_s: float = Field(0.1, gt=0.0)  # [s]
        pos_tol_m: float = Field(0.3, gt=0.0)  # [m]
        heading_tol_rad: float = Field(0.05, gt=0.0)  # [rad]
        either_direction: bool = False  # nose-in and reversed-in both count
        stop_mps: float = Field(0.05, gt=0.0)  # [m/s] moving above this
        direction_mps: float = Field(0.2, gt=0.0)  # [m/s] a direction of travel counts above this

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.min_clear = math.inf
        self.first_move = math.nan
        self.last_move = math.nan
        self.changes = 0
        self._dir = 0
        self.final: tuple[float, float, float] | None = None  # (pos err, heading err, v)
        self.parked: np.ndarray | None = None  # (m, 4, 2) the parked cars of the first snapshot
        self._prev: tuple[float, np.ndarray] | None = None  # (t [s], ego centre xy [m])
        self._driven: list[tuple[float, float, float]] = []  # (t [s], x [m], y [m]) of the ego's centre

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        rows = np.flatnonzero(s.ids == self.p.ego)
        if not len(rows):
            return
        k = int(rows[0])
        if self.parked is None:  # the cars standing when the ego appears (slot ground truth)
            cars = np.flatnonzero((s.ids != self.p.ego) & (s.kind == Kind.CAR) & (s.speed < 0.01))
            self.parked = box_polygons(s.position[cars, :2], s.heading[cars], s.size[cars, 0], s.size[cars, 1])
        goal = self._goal(ctx)
        self._driven.append((ctx.t, float(s.position[k, 0]), float(s.position[k, 1])))
        h = float(s.heading[k])
        v = self._signed_speed(ctx.t, s.position[k, :2], h)
        others = np.flatnonzero(s.ids != self.p.ego)
        if len(others):
            me = box_polygons(s.position[k, :2], np.array([h]), s.size[k:k + 1, 0], s.size[k:k + 1, 1])[0]
            polys = box_polygons(s.position[others, :2], s.heading[others], s.size[others, 0], s.size[others, 1])
            clear = float(clearances(me, polys).min())
            self.min_clear = min(self.min_clear, clear)
            ctx.signals.record("clearance", ctx.t, clear)
        if abs(v) > self.p.stop_mps:
            if math.isnan(self.first_move):
                self.first_move = ctx.t
            self.last_move = ctx.t
        if abs(v) > self.p.direction_mps:
            d = 1 if v > 0 else -1
            if self._dir and d != self._dir:
                self.changes += 1
            self._dir = d
        if goal is None:
            return
        pos_err = float(np.hypot(*(s.position[k, :2] - goal[:2])))
        dh = (h - goal[2] + math.pi) % (2 * math.pi) - math.pi
        if self.p.either_direction:
            dh = min(abs(dh), math.pi - abs(dh))
        self.final = (pos_err, abs(dh), v)
        ctx.signals.record("speed", ctx.t, v)
        ctx.signals.record("pos_err", ctx.t, pos_err)

    def _signed_speed(self, t: float, xy: np.ndarray, heading: float) -> float:
        """[m/s] from the displacement along the heading since the last period (a backend's velocity
        may carry no sign: SUMO reports a reversing car's speed as positive)."""
        prev, self._prev = self._prev, (t, xy.copy())
        if prev is None or t <= prev[0]:
            return 0.0
        return float((xy - prev[1]) @ np.array([math.cos(heading), math.sin(heading)]) / (t - prev[0]))

    @staticmethod
    def _goal(ctx: RunContext) -> np.ndarray | None:
        """(x, y, heading) of the goal box centre: the lot's goal bay, else the last ``goal`` event."""
        lot = ctx.snapshot.road.tables.landmarks if ctx.snapshot.road is not None else None
        if hasattr(lot, "goal_centre"):
            return np.array([*lot.goal_centre, lot.goal_heading])
        goals = ctx.events.of_kind("goal")
        return np.array([goals[-1].data["x"], goals[-1].data["y"], goals[-1].data["heading"]]) if goals else None

    def _score_slots(self, ctx: RunContext) -> dict[str, Any]:
        tp = n_found = n_true = 0
        for ev in ctx.events.of_kind("slots"):
            d = ev.data
            if d.get("extent") is None or self.parked is None:
                continue
            truth = true_slots(self.parked, np.asarray(d["origin"]), np.asarray(d["direction"]), int(d["side"]),
                               tuple(d["band_m"]), tuple(d["extent"]), float(d["need_m"]))
            a, b, c = match_slots([Slot(*x) for x in d["slots"]], truth)
            tp, n_found, n_true = tp + a, n_found + b, n_true + c
        return {"slot_precision": tp / n_found if n_found else math.nan,
                "slot_recall": tp / n_true if n_true else math.nan,
                "slots_detected": n_found, "slots_true": n_true}

    def _write_lot(self, ctx: RunContext) -> None:
        """The lot, the plans and the driven path, for the report (``parking/lot-<run_id>.json``)."""
        marks = ctx.snapshot.road.tables.landmarks if ctx.snapshot.road is not None else None
        outlines = marks.outlines() if callable(getattr(marks, "outlines", None)) else {}
        goal = self._goal(ctx)
        doc = {"outlines": {k: [np.asarray(q, float).tolist() for q in v] for k, v in outlines.items()},
               "parked": [] if self.parked is None else np.asarray(self.parked, float).tolist(),
               "goal": None if goal is None else [float(x) for x in goal],
               "plans": [{"t": ev.t, "xy": np.asarray(ev.data["polyline"], float).tolist()}
                         for ev in ctx.events.of_kind("plan") if ev.data.get("polyline") is not None],
               "driven": self._driven}
        ctx.output_path(LOT_FILE).write_text(json.dumps(doc))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._write_lot(ctx)
        if self.final is None:
            out = {c: math.nan for c in self.metric_columns()}
            return {**out, "success": 0, **self._score_slots(ctx)}
        pos, head, v = self.final
        goals = ctx.events.of_kind("goal")  # a street's manoeuvre starts when its slot is chosen
        start = max(self.first_move, goals[0].t) if goals and not math.isnan(self.first_move) else self.first_move
        ok = pos <= self.p.pos_tol_m and head <= self.p.heading_tol_rad and abs(v) < self.p.stop_mps
        return {
            "success": int(ok),
            "pos_err_m": pos,
            "heading_err_rad": head,
            "min_clearance_m": self.min_clear if math.isfinite(self.min_clear) else math.nan,
            "manoeuvre_time_s": self.last_move - start if not math.isnan(start) else 0.0,
            "direction_changes": self.changes,
            **self._score_slots(ctx),
        }

    def metric_columns(self) -> frozenset[str]:
        return frozenset({"success", "pos_err_m", "heading_err_rad", "min_clearance_m", "manoeuvre_time_s",
                          "direction_changes", "slot_precision", "slot_recall", "slots_detected", "slots_true"})
