"""The fidelity policy on hand-made states: ``promote_on: proximity`` promotes every pair inside the
boundary, ``converging`` only the pairs closing on each other (side-by-side and parting aircraft stay
or go back to point masses)."""

from __future__ import annotations

import numpy as np

from corridor.vehicles.air.fidelity import FidelityParams, FidelityPolicy

BOUNDARY = {"promote_radius_m": 65.0, "promote_vertical_m": 17.0, "promote_ttca_s": 3.0, "demote_radius_m": 90.0,
            "min_dwell_s": 1.0}


def decide(promote_on: str, pos: list[list[float]], vel: list[list[float]], six: bool) -> tuple[list[int], list[int]]:
    policy = FidelityPolicy(FidelityParams(promote_on=promote_on, **BOUNDARY))
    n = len(pos)
    promote, demote = policy.decide(np.array(pos, float), np.array(vel, float), np.zeros(n, bool), np.full(n, six),
                                    np.zeros(n), t_s=10.0)
    return promote.tolist(), demote.tolist()


SIDE_BY_SIDE = ([[0, 0, 60], [0, 30, 60]], [[7, 0, 0], [7, 0, 0]])
PARTING = ([[0, 0, 60], [30, 0, 60]], [[-7, 0, 0], [7, 0, 0]])
HEAD_ON = ([[0, 0, 60], [80, 10, 60]], [[7, 0, 0], [-7, 0, 0]])  # 80 m apart, closing at 14 m/s, miss 10 m


def test_side_by_side_pair_is_promoted_by_proximity_only() -> None:
    assert decide("proximity", *SIDE_BY_SIDE, six=False) == ([0, 1], [])
    assert decide("converging", *SIDE_BY_SIDE, six=False) == ([], [])


def test_parting_pair_stays_6dof_by_proximity_and_is_demoted_when_converging() -> None:
    assert decide("proximity", *PARTING, six=True) == ([], [])
    assert decide("converging", *PARTING, six=True) == ([], [0, 1])


def test_closing_pair_is_promoted_by_both_and_kept_while_it_closes() -> None:
    assert decide("proximity", *HEAD_ON, six=False) == ([0, 1], [])
    assert decide("converging", *HEAD_ON, six=False) == ([0, 1], [])
    assert decide("converging", *HEAD_ON, six=True) == ([], [])


def test_slow_closure_below_closing_min_is_not_a_pair() -> None:
    pos, vel = [[0, 0, 60], [0, 40, 60]], [[7, 0, 0], [7, -0.3, 0]]  # closing at 0.3 m/s < 0.5 m/s
    assert decide("converging", pos, vel, six=False) == ([], [])


def test_encounter_is_flown_6dof_from_closing_to_beyond_the_demotion_boundary() -> None:
    """``encounter``: side by side never starts one; a head-on pair starts one, stays 6-DOF after its
    closest approach while it parts inside the demotion boundary (``converging`` demotes it there),
    and is demoted once it is beyond it."""
    assert decide("encounter", *SIDE_BY_SIDE, six=False) == ([], [])
    policy = FidelityPolicy(FidelityParams(promote_on="encounter", **BOUNDARY))
    none, two = np.zeros(2, bool), np.ones(2, bool)

    def step(pos: list[list[float]], vel: list[list[float]], six: np.ndarray) -> tuple[list[int], list[int]]:
        promote, demote = policy.decide(np.array(pos, float), np.array(vel, float), none, six, np.zeros(2), 10.0)
        return promote.tolist(), demote.tolist()

    assert step(*HEAD_ON, six=none) == ([0, 1], [])
    assert step(*PARTING, six=two) == ([], [])  # 30 m apart, parting at 14 m/s: the encounter runs on
    assert step([[0, 0, 60], [60, 0, 60]], [[-7, 0, 0], [7, 0, 0]], six=two) == ([], [])  # 60 m apart: inside 90 m
    assert step([[0, 0, 60], [100, 0, 60]], [[-7, 0, 0], [7, 0, 0]], six=two) == ([], [0, 1])
    assert step(*PARTING, six=none) == ([], [])  # the encounter is over: parting pairs do not start one
