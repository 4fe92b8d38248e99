"""Shared paths and the closed-form truth of the rare-event tests."""

from __future__ import annotations

from pathlib import Path

from scipy.stats import norm

GAUSS = Path(__file__).resolve().parent / "data" / "gauss_tail.yaml"
# NMAC iff 45 < x < 105.96 with x ~ N(0, 10): the input beyond 4.5 sigma
TRUTH = float(norm.sf(4.5) - norm.sf(10.596))

TWO_MODES = Path(__file__).resolve().parent / "data" / "two_modes.yaml"
# failure iff x > 35 m (x ~ N(0, 10)) or y > 12 m (y ~ N(0, 3)): two half-planes
P_X, P_Y = float(norm.sf(3.5)), float(norm.sf(4.0))
TWO_MODES_TRUTH = 1 - (1 - P_X) * (1 - P_Y)
