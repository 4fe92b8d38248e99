"""Scenario entry point: evaluate one STL specification on one run's recorded signals."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from corridor.stl.formula import Formula
from corridor.stl.parser import as_formula
from corridor.stl.space import check_dt, check_signals, space_robustness
from corridor.stl.time_rob import time_robustness


@dataclass(frozen=True)
class SpecResult:
    """Robustness of a specification at t = 0.

    ``satisfied`` is the exact Boolean semantics (the sign of the time robustness, which is never 0),
    so with a space robustness of exactly 0 it tells strict from non-strict predicates apart. When the
    value at t = 0 reads a missing (NaN) sample, ``space`` and the time values are NaN and
    ``satisfied`` is False: unknown never counts as satisfied.
    ``space`` is in the signal's units, ``time_left`` / ``time_right`` / ``time`` (combined) in
    seconds, ``trace`` the space robustness at every sample.
    """

    satisfied: bool
    space: float
    time_left: float  # [s]
    time_right: float  # [s]
    time: float  # [s]
    trace: np.ndarray


def evaluate_spec(formula: str | Formula, signals: Mapping[str, np.ndarray], dt: float) -> SpecResult:
    """Space and time robustness of ``formula`` over signals sampled every ``dt`` seconds."""
    dt = check_dt(dt)
    tree = as_formula(formula)
    _, n = check_signals(tree, signals)
    if n == 0:
        raise ValueError("cannot evaluate a specification on empty signals")
    trace = space_robustness(tree, signals, dt)
    theta = time_robustness(tree, signals, dt)
    return SpecResult(
        satisfied=bool(theta.right[0] > 0) and not np.isnan(trace[0]),  # NaN > 0 is False too
        space=float(trace[0]),
        time_left=float(theta.left[0]),
        time_right=float(theta.right[0]),
        time=float(theta.combined[0]),
        trace=trace,
    )
