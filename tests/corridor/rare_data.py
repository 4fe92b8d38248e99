"""Shared paths and the closed-form truth of the rare-event tests."""

from __future__ import annotations

from pathlib import Path

from scipy.stats import norm

GAUSS = Path(__file__).resolve().parent / "data" / "gauss_tail.yaml"
# NMAC iff 45 < x < 105.96 with x ~ N(0, 10): the input beyond 4.5 sigma
TRUTH = float(norm.sf(4.5) - norm.sf(10.596))
