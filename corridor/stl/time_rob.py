"""Left, right and combined time robustness (Donzé & Maler, FORMATS 2010).

Time robustness asks how far in time a signal can be shifted before the satisfaction of a formula
changes. Donzé & Maler define it on the Boolean satisfaction signal ``chi`` (+1 / -1) of each
predicate ``p``::

    theta+(p, t) = chi(p, t) * sup{ d >= 0 : chi(p, t') = chi(p, t) for all t' in [t, t + d] }
    theta-(p, t) = chi(p, t) * sup{ d >= 0 : chi(p, t') = chi(p, t) for all t' in [t - d, t] }

and extend it to formulas with the same recursive min/max rules as space robustness (negation
flips the sign, ``&`` is min, ``G``/``F``/``U`` take min/max over the interval). We implement that
definition in discrete time with a zero-order hold: sample ``k`` stands for ``[k*dt, (k+1)*dt)``, so
``theta+[k] = chi[k] * dt * (samples from k to the end of its run of equal chi, k included)`` and
``theta-[k] = chi[k] * dt * (samples from the start of its run to k)``. Runs are capped by the trace:
a run that reaches the end (start) of the recording counts only the recorded samples, so
``|theta| <= n*dt``. The magnitude is never 0, so ``sign(theta)`` is the exact Boolean satisfaction.

**NaN** (unknown satisfaction, see ``space``): at a sample where the predicate's robustness is NaN,
``chi`` and all three robustness values are NaN, and the runs of known satisfaction around it are
capped there exactly as they are capped at the ends of the recording (the unknown sample is neither
equal nor different). Operators then propagate NaN like space robustness, so time robustness is NaN
at exactly the indices where space robustness is, and its sign is the Boolean satisfaction elsewhere.

The combined robustness ``theta+-`` follows Rodionova, Lindemann, Morari & Pappas, "Combined left and
right temporal robustness for control under STL specifications" (IEEE L-CSS 2023): at a predicate,
``theta+-(p, t) = chi(p, t) * min(|theta-(p, t)|, |theta+(p, t)|)`` (the largest symmetric
neighbourhood of equal satisfaction), propagated with the same recursive rules.

Runs are found with one ``np.diff``; every pass is linear in the trace length.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from corridor.stl.formula import Formula, Predicate
from corridor.stl.parser import as_formula
from corridor.stl.space import (
    check_dt,
    check_signals,
    evaluate_tree,
    predicate_holds,
    predicate_robustness,
)


@dataclass(frozen=True)
class TimeRobustness:
    """Traces of left, right and combined time robustness [s], one value per sample."""

    left: np.ndarray
    right: np.ndarray
    combined: np.ndarray


def run_lengths(holds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: samples back to its run's start and forward to its run's end (both inclusive).

    ``holds`` may be Boolean or any discrete state (e.g. +1 / -1 / 0 for unknown)."""
    n = holds.size
    index = np.arange(n)
    change = np.flatnonzero(holds[1:] != holds[:-1]) + 1  # first index of each new run
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [n])) - 1
    run_id = np.repeat(np.arange(starts.size), np.diff(np.concatenate((starts, [n]))))
    return index - starts[run_id] + 1, ends[run_id] - index + 1


def predicate_time_robustness(holds: np.ndarray, dt: float, unknown: np.ndarray | None = None) -> TimeRobustness:
    """theta-, theta+ and theta+- of one Boolean satisfaction signal; NaN where ``unknown``."""
    state = np.where(holds, 1, -1)
    if unknown is not None:
        state[unknown] = 0  # a run of its own: caps its neighbours' runs like the end of the trace
    chi = state.astype(float)
    chi[state == 0] = np.nan
    back, forward = run_lengths(state)
    return TimeRobustness(chi * dt * back, chi * dt * forward, chi * dt * np.minimum(back, forward))


def time_robustness(spec: str | Formula, signals: Mapping[str, np.ndarray], dt: float) -> TimeRobustness:
    """Left, right and combined time robustness traces of the formula at every sample."""
    dt = check_dt(dt)
    formula = as_formula(spec)
    arrays, n = check_signals(formula, signals)
    leaves: dict[Predicate, TimeRobustness] = {}

    def leaf(pred: Predicate) -> TimeRobustness:
        if pred not in leaves:
            rho = predicate_robustness(pred, arrays, n)
            leaves[pred] = predicate_time_robustness(predicate_holds(pred, rho), dt, np.isnan(rho))
        return leaves[pred]

    return TimeRobustness(
        left=evaluate_tree(formula, lambda p: leaf(p).left, dt),
        right=evaluate_tree(formula, lambda p: leaf(p).right, dt),
        combined=evaluate_tree(formula, lambda p: leaf(p).combined, dt),
    )
