"""Loop-detector faults as a scenario input: a share of the loop stations fails at random times.

A *station* is the group of loops across the lanes at one place (up- or downstream of a merge, as the
ramp detectors aggregate them).  ``share`` of the stations fail, each at a time drawn uniformly in
``start_s`` and in a mode drawn from ``modes``:

- ``stuck_zero``: the station reports 0 % occupancy, 0 veh/h and no speed from then on (a broken
  loop or a cut cable on a controller that still answers);
- ``dropout``: the station sends nothing; the centre holds the last values it received (the usual
  substitution of a traffic centre), so its picture freezes;
- ``bias``: occupancy and flow are scaled by ``bias_factor`` (a detuned loop undercounting).

Which stations fail, when and how is drawn from the component's own random stream, so every variant
of one seed sees the same faults (common random numbers) and ``share: 0`` means healthy loops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

FaultMode = Literal["stuck_zero", "dropout", "bias"]


class LoopFaults(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    share: float = Field(0.0, ge=0.0, le=1.0)  # of the loop stations
    modes: list[FaultMode] = Field(default_factory=lambda: ["stuck_zero", "dropout", "bias"], min_length=1)
    start_s: tuple[float, float] = (30.0, 300.0)  # [s] failure time window (uniform): before and in the peak
    bias_factor: float = Field(0.4, ge=0.0)  # bias: reported = factor x true (occupancy, flow)

    @model_validator(mode="after")
    def _window(self) -> LoopFaults:
        if not 0.0 <= self.start_s[0] <= self.start_s[1]:
            raise ValueError(f"start_s must be [lo, hi] with 0 <= lo <= hi, got {list(self.start_s)}")
        return self


@dataclass(frozen=True)
class StationFault:
    mode: str
    t_fail_s: float  # [s]


@dataclass
class Reading:
    """One station's interval values: occupancy [%], flow [veh/h], speed [m/s] (nan: none); ``ok``:
    the centre received this interval (False: it holds the previous values)."""

    occupancy_pct: float
    flow_vph: float
    speed_mps: float
    ok: bool = True


def draw_faults(cfg: LoopFaults, stations: list[str], rng: np.random.Generator) -> dict[str, StationFault]:
    """Station -> its fault (stations not in the result stay healthy). ``round(share x count)`` fail."""
    n_fail = int(round(cfg.share * len(stations)))
    order = rng.permutation(len(stations))  # drawn even when nothing fails: the stream stays aligned
    times = rng.uniform(cfg.start_s[0], cfg.start_s[1], len(stations))
    modes = rng.integers(0, len(cfg.modes), len(stations))
    return {stations[i]: StationFault(cfg.modes[int(modes[i])], float(times[i])) for i in order[:n_fail]}


def apply_fault(fault: StationFault | None, t_s: float, true: Reading, held: Reading | None,
                bias_factor: float) -> Reading:
    """What the centre gets from a station at ``t_s`` (``held``: the last values it received)."""
    if fault is None or t_s < fault.t_fail_s:
        return true
    if fault.mode == "stuck_zero":
        return Reading(0.0, 0.0, math.nan)
    if fault.mode == "bias":
        return Reading(true.occupancy_pct * bias_factor, true.flow_vph * bias_factor, true.speed_mps)
    h = held or Reading(0.0, 0.0, math.nan)
    return Reading(h.occupancy_pct, h.flow_vph, h.speed_mps, ok=False)
