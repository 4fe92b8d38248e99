"""The STL specifications of a scenario as a monitor: ``specs`` declared in the YAML are evaluated
on the run's recorded signals when the run ends, giving ``spec.<name>.{satisfied,space,time}``.

The engine adds this monitor (registry name ``stl_specs``) as the last component of every run whose
scenario declares ``specs``, so its ``finish`` sees every signal the other components recorded.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from corridor.engine import Component, Metric, Phase, RunContext
from corridor.stl import STLSignalError, as_formula, evaluate_spec


class SpecMonitor(Component):
    """Evaluates ``scenario.specs`` at the end of the run (it measures nothing per tick)."""

    phase = Phase.RECORD
    period_source: ClassVar[str | None] = "run"  # one no-op tick at t = 0
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric("spec.*.satisfied", "1", "1 if the run satisfied STL spec <name> (a violation counts in the verdict)."),
        Metric("spec.*.space", "1", "Space robustness of STL spec <name>: > 0 satisfied with that margin, in the "
               "units of the signals it compares."),
        Metric("spec.*.time", "s", "Time robustness of STL spec <name>: how far in time the signals could shift "
               "and keep the verdict."),
    )

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.scenario = scenario

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return evaluate_specs(self.scenario, ctx)


def evaluate_specs(sc: Any, ctx: RunContext) -> dict[str, Any]:
    """Evaluate the scenario's STL specs on the recorded signals, resampled to the base tick.

    Resampling never invents a measurement. A spec's t = 0 is the first recorded sample of the signals
    it reads (a vehicle that enters at 60 s is judged from its entry, not on its first value copied
    back to the start of the run) and its trace ends at their last sample. Between two samples a signal
    is interpolated linearly only when they are at most 1.5 of its recording periods (median interval)
    apart; across a longer gap, before a signal starts and after it stops it is NaN, which the STL
    semantics never counts as satisfied. A spec reading a signal that was never recorded is an error
    (the run becomes an error row), never judged on zeros.
    """
    if not sc.specs:
        return {}

    def _resample(t: np.ndarray, v: np.ndarray, grid: np.ndarray, dt: float) -> np.ndarray:
        """``v(t)`` on ``grid``: linear between samples at most 1.5 periods apart, NaN elsewhere (no data)."""
        tol = 1e-6 * dt  # [s] a grid time this close to a sample time is that sample
        g = np.clip(grid, t[0], t[-1])
        inside = np.abs(g - grid) <= tol
        if t.size == 1:
            return np.where(inside, v[0], np.nan)
        max_gap = 1.5 * float(np.median(np.diff(t)))  # [s]
        i = np.clip(np.searchsorted(t, g, side="right"), 1, t.size - 1)  # t[i-1] <= g <= t[i]
        on_sample = (np.abs(g - t[i - 1]) <= tol) | (np.abs(g - t[i]) <= tol)
        known = inside & (on_sample | (t[i] - t[i - 1] <= max_gap))
        return np.where(known, np.interp(g, t, v), np.nan)

    out: dict[str, Any] = {}
    for spec in sc.specs:
        formula = as_formula(spec.formula)
        names = sorted(formula.signal_names())
        missing = [n for n in names if n not in ctx.signals.names() or not len(ctx.signals.get(n)[0])]
        if missing:
            known = ", ".join(sorted(ctx.signals.names())) or "none"
            raise STLSignalError(f"spec {spec.name!r}: signal '{missing[0]}' is not recorded (known: {known})")
        recorded = {n: ctx.signals.get(n) for n in names}
        start = min((float(t[0]) for t, _ in recorded.values()), default=0.0)
        end = max((float(t[-1]) for t, _ in recorded.values()), default=sc.duration)
        grid = start + sc.dt * np.arange(int(np.floor((end - start) / sc.dt + 1e-6)) + 1)
        signals = {n: _resample(t, v, grid, sc.dt) for n, (t, v) in recorded.items()} or {"t": grid}
        r = evaluate_spec(formula, signals, sc.dt)
        out[f"spec.{spec.name}.satisfied"] = bool(r.satisfied)
        out[f"spec.{spec.name}.space"] = float(r.space)
        out[f"spec.{spec.name}.time"] = float(r.time)
    return out
