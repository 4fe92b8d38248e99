"""Breakdown and capacity drop of a bottleneck, from interval series of loop flows and speeds (pure numpy).

Definitions (sources in ``docs/guide/merging-calibration.md``):

* breakdown (Highway Capacity Manual): the first interval at which the upstream station's mean speed is
  at least ``speed_drop`` (25 %) below the free-flow speed and stays so for ``sustain_s``;
* pre-breakdown maximum flow: the largest ``window_s`` moving average of the downstream flow over the
  intervals that end at or before the breakdown (Cassidy & Bertini 1999 compare the flow before the
  queue forms with the queue discharge flow);
* queue discharge flow: the mean downstream flow from ``transition_s`` after the breakdown to the end;
* capacity drop = 1 - discharge / pre-breakdown maximum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Breakdown:
    """What the series show; times are interval ends [s], flows [veh/h]; nan when there is no breakdown."""

    free_flow_speed_mps: float
    breakdown_s: float
    prebreakdown_flow_vph: float
    discharge_flow_vph: float

    @property
    def occurred(self) -> bool:
        return not math.isnan(self.breakdown_s)

    @property
    def capacity_drop(self) -> float:
        """1 - discharge / pre-breakdown maximum (a fraction; nan without a breakdown)."""
        if not self.occurred or not self.prebreakdown_flow_vph > 0:
            return math.nan
        return 1.0 - self.discharge_flow_vph / self.prebreakdown_flow_vph


def breakdown_time(t_s: np.ndarray, speed_mps: np.ndarray, free_flow_mps: float, speed_drop: float,
                   sustain_s: float) -> float:
    """First interval end at which the speed is below (1 - speed_drop) x free flow for ``sustain_s``
    (every interval from it to ``sustain_s`` later; an interval nobody crossed counts as slow: a
    standing queue); nan if none (or if the run ends before the breakdown was sustained)."""
    slow = ~(speed_mps >= (1.0 - speed_drop) * free_flow_mps)  # nan (nobody passed) is slow
    for k in np.flatnonzero(slow):
        held = (t_s >= t_s[k]) & (t_s <= t_s[k] + sustain_s)
        if t_s[-1] >= t_s[k] + sustain_s and slow[held].all():
            return float(t_s[k])
    return math.nan


def moving_mean(values: np.ndarray, n: int) -> np.ndarray:
    """Means of every ``n`` consecutive values (empty if there are fewer)."""
    if n < 1 or len(values) < n:
        return np.zeros(0)
    c = np.concatenate([[0.0], np.cumsum(values)])
    return (c[n:] - c[:-n]) / n


def analyse(t_s: np.ndarray, up_speed_mps: np.ndarray, down_flow_vph: np.ndarray, interval_s: float,
            free_flow_mps: float, speed_drop: float = 0.25, sustain_s: float = 300.0,
            window_s: float = 300.0, transition_s: float = 120.0) -> Breakdown:
    """Breakdown time, pre-breakdown maximum flow and queue discharge flow of one run."""
    tb = breakdown_time(t_s, up_speed_mps, free_flow_mps, speed_drop, sustain_s)
    if math.isnan(tb):
        return Breakdown(free_flow_mps, math.nan, math.nan, math.nan)
    before = down_flow_vph[t_s <= tb]
    avg = moving_mean(before, max(1, round(window_s / interval_s)))
    pre = float(avg.max()) if len(avg) else math.nan
    after = down_flow_vph[t_s > tb + transition_s]
    return Breakdown(free_flow_mps, tb, pre, float(after.mean()) if len(after) else math.nan)
