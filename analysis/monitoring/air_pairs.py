"""Separation by class of pair (``monitor.air_pairs``): patrol UAV - patrol UAV, patrol UAV - aircraft
(the piloted c172x) and patrol UAV - medical drone, each with its minimum horizontal and 3-D
separation and its NMAC / loss-of-separation count (thresholds of ``SeparationMonitor``: sNMAC
30.48 m / 4.572 m for every pair; LoS 60.96 m / 15.24 m between UAVs, the 609.6 m / 76.2 m "well
clear" volume against the piloted aircraft and the medical drone).

Reads only the snapshot rows of the named aircraft, at the monitor's period (default: every tick);
a pair entering a volume counts once per entry.  (``uav_separation`` gives the all-pairs figures with
continuous detection between ticks; this one splits them by class, checked at the ticks.)
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Phase, RunContext
from corridor.snapshot import Kind


class AirPairs(Component):
    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('sep_min_*_m', 'm',
               'Smallest 3-D distance within a pair class (uav_uav, uav_aircraft, uav_medical; sep_min_h_*: horizontal).'),
        Metric('nmac_*', '1',
               'NMACs within a pair class (uav_uav, uav_aircraft, uav_medical).', safety_event=True),
        Metric('los_*', '1',
               'Losses of separation within a pair class (uav_uav, uav_aircraft, uav_medical).', safety_event=True),
    )
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        prefix: str = "patrol_"  # ids of the patrol UAVs start with this
        aircraft: list[str] = Field(default_factory=lambda: ["c172"])
        medical: list[str] = Field(default_factory=lambda: ["medical"])
        nmac_h_m: float = Field(30.48, gt=0.0)
        nmac_v_m: float = Field(4.572, gt=0.0)
        los_h_m: float = Field(60.96, gt=0.0)
        los_v_m: float = Field(15.24, gt=0.0)
        los_priority_h_m: float = Field(609.6, gt=0.0)
        los_priority_v_m: float = Field(76.2, gt=0.0)

    CLASSES = ("uav_uav", "uav_aircraft", "uav_medical")

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.pairs: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.ids: list[str] = []
        self.min_h = dict.fromkeys(self.CLASSES, math.inf)
        self.min_3d = dict.fromkeys(self.CLASSES, math.inf)
        self.nmac = dict.fromkeys(self.CLASSES, 0)
        self.los = dict.fromkeys(self.CLASSES, 0)

    def _build(self, ids: list[str]) -> None:
        p = self.params
        patrol = [k for k, i in enumerate(ids) if i.startswith(p.prefix)]
        ii, jj, cls = [], [], []
        for a, ka in enumerate(patrol):
            for kb in patrol[a + 1:]:
                ii.append(ka), jj.append(kb), cls.append(0)
            for kb, i in enumerate(ids):
                if i in p.aircraft or i in p.medical:
                    ii.append(ka), jj.append(kb), cls.append(1 if i in p.aircraft else 2)
        self.ids = ids
        self.pairs = (np.array(ii, dtype=int), np.array(jj, dtype=int), np.array(cls, dtype=int))
        c = self.pairs[2]
        self.los_h = np.where(c == 0, p.los_h_m, p.los_priority_h_m)
        self.los_v = np.where(c == 0, p.los_v_m, p.los_priority_v_m)
        self.in_nmac = np.zeros(len(c), dtype=bool)
        self.in_los = np.zeros(len(c), dtype=bool)

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        air = np.flatnonzero((s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT))
        if len(air) == 0:
            return
        ids = [str(i) for i in s.ids[air]]
        if ids != self.ids:
            self._build(ids)
        i, j, cls = self.pairs
        if len(i) == 0:
            return
        pos = s.position[air]
        d = pos[i] - pos[j]
        dh = np.hypot(d[:, 0], d[:, 1])
        dv = np.abs(d[:, 2])
        d3 = np.sqrt(dh**2 + dv**2)
        p = self.params
        nmac = (dh < p.nmac_h_m) & (dv < p.nmac_v_m)
        los = (dh < self.los_h) & (dv < self.los_v)
        for c, name in enumerate(self.CLASSES):
            m = cls == c
            if m.any():
                self.min_h[name] = min(self.min_h[name], float(dh[m].min()))
                self.min_3d[name] = min(self.min_3d[name], float(d3[m].min()))
                self.nmac[name] += int(np.count_nonzero(nmac[m] & ~self.in_nmac[m]))
                self.los[name] += int(np.count_nonzero(los[m] & ~self.in_los[m]))
        for k in np.flatnonzero(nmac & ~self.in_nmac):
            ctx.events.emit(ctx.t, self.name, "nmac", f"{ids[i[k]]} - {ids[j[k]]}: {dh[k]:.1f} m / {dv[k]:.1f} m")
        self.in_nmac, self.in_los = nmac, los
        if (cls == 0).any():
            ctx.signals.record("sep_uav_uav_m", ctx.t, float(d3[cls == 0].min()))
        if (cls > 0).any():
            ctx.signals.record("sep_uav_priority_m", ctx.t, float(d3[cls > 0].min()))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name in self.CLASSES:
            out[f"sep_min_{name}_m"] = self.min_3d[name] if math.isfinite(self.min_3d[name]) else math.nan
            out[f"sep_min_h_{name}_m"] = self.min_h[name] if math.isfinite(self.min_h[name]) else math.nan
            out[f"nmac_{name}"] = self.nmac[name]
            out[f"los_{name}"] = self.los[name]
        return out
