"""TPCAP-format cases built for the tests: each reproduces one way a held-out case broke the planner
(far coordinates, a goal that clears its nearest obstacle by 0.17 m, a cluttered lot).

All are `Case`s (rear-axle poses, polygon obstacles) and can be written with `format_case`.
"""

from __future__ import annotations

import math

import numpy as np

from corridor.controllers.parking.case import Case
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, Obstacles, footprint

VEH = TPCAP_VEHICLE
CAR_L, CAR_W = VEH.length_m, VEH.width_m  # [m] parked cars are the benchmark's car


def rect(cx: float, cy: float, length: float, width: float, heading: float = 0.0) -> np.ndarray:
    """Corners (4, 2) of a box centred at (cx, cy), ``length`` along ``heading`` (counter-clockwise)."""
    c, s = math.cos(heading), math.sin(heading)
    local = np.array([[-length / 2, -width / 2], [length / 2, -width / 2], [length / 2, width / 2],
                      [-length / 2, width / 2]])
    return np.column_stack([cx + c * local[:, 0] - s * local[:, 1], cy + s * local[:, 0] + c * local[:, 1]])


def shifted(case: Case, dx: float, dy: float) -> Case:
    """The same case moved by (dx, dy) [m] (TPCAP gives some cases at ~1e9 m)."""
    d = np.array([dx, dy])
    return Case(start=(case.start[0] + dx, case.start[1] + dy, case.start[2]),
                goal=(case.goal[0] + dx, case.goal[1] + dy, case.goal[2]),
                obstacles=tuple(np.asarray(p) + d for p in case.obstacles))


def clearance(case: Case, pose: tuple[float, float, float]) -> float:
    """Distance [m] from the footprint at ``pose`` to the nearest obstacle (shapely, independent)."""
    import shapely

    fp = shapely.Polygon(footprint(np.array([pose]), VEH)[0])
    return float(min(fp.distance(shapely.Polygon(p)) for p in case.obstacles))


def tight_perpendicular(gap_m: float = 0.17, aisle_m: float = 6.0) -> Case:
    """Reverse into a bay between two parked cars, each ``gap_m`` beside the goal footprint, a kerb
    ``gap_m`` behind it; the aisle is ``aisle_m`` wide with a wall on the far side."""
    bay_w = CAR_W + 2 * gap_m
    # goal: rear axle in the bay, nose towards the aisle (y = 0 is the bay mouth, bays below)
    rear = -(CAR_L + gap_m) + VEH.rear_hang_m
    goal = (0.0, rear, math.pi / 2)
    obstacles = [rect(-(bay_w / 2 + CAR_W / 2), -CAR_L / 2, CAR_W, CAR_L),
                 rect(+(bay_w / 2 + CAR_W / 2), -CAR_L / 2, CAR_W, CAR_L),
                 rect(0.0, -(CAR_L + 2 * gap_m) - 0.5, 14.0, 1.0),  # kerb behind the bays
                 rect(0.0, aisle_m + 0.5, 30.0, 1.0)]  # wall across the aisle
    # more parked cars further along the row
    for k in (2, 3):
        for side in (-1, 1):
            obstacles.append(rect(side * (bay_w / 2 + CAR_W / 2 + (k - 1) * (CAR_W + 0.6)), -CAR_L / 2, CAR_W, CAR_L))
    start = (-9.0, aisle_m / 2, 0.0)
    return Case(start=start, goal=goal, obstacles=tuple(obstacles))


def tight_parallel(gap_m: float = 0.17, slot_extra_m: float = 2.2) -> Case:
    """Reverse into a parallel slot beside a kerb ``gap_m`` from the goal footprint, between two
    parked cars (``slot_extra_m`` longer than the car in all, the goal centred); a lane of 3.5 m and
    a wall beyond it."""
    kerb_y = 0.0
    goal_y = kerb_y + gap_m + CAR_W / 2
    slot = CAR_L + slot_extra_m
    # goal centred in the slot, heading +x: rear axle at the footprint's rear + rear overhang
    goal = (-CAR_L / 2 + VEH.rear_hang_m, goal_y, 0.0)
    obstacles = [rect(0.0, kerb_y - 0.5, 30.0, 1.0),  # kerb
                 rect(-slot / 2 - CAR_L / 2, goal_y, CAR_L, CAR_W),  # car behind
                 rect(slot / 2 + CAR_L / 2, goal_y, CAR_L, CAR_W),  # car ahead
                 rect(0.0, goal_y + CAR_W / 2 + 3.5 + 0.8 + 0.5, 30.0, 1.0)]  # wall across the lane
    start = (slot / 2 + CAR_L + 1.0, goal_y + CAR_W / 2 + 0.3 + 0.8 + CAR_W / 2, 0.0)
    return Case(start=start, goal=goal, obstacles=tuple(obstacles))


def cluttered(n: int = 37, seed: int = 0, size_m: float = 36.0) -> Case:
    """A lot of ``n`` obstacles (rotated boxes of 0.5 to 2.5 m) scattered over a ``size_m`` square
    around a start on its left and a goal on its right, none within 1.2 m of either footprint."""
    rng = np.random.default_rng(seed)
    start, goal = (-size_m / 2 + 4.0, 0.0, 0.0), (size_m / 2 - 8.0, 2.0, math.pi / 2)
    keep = Obstacles([footprint(np.array([p]), VEH)[0] for p in (start, goal)])
    polys: list[np.ndarray] = []
    while len(polys) < n:
        cx, cy = rng.uniform(-size_m / 2, size_m / 2, 2)
        box = rect(cx, cy, *rng.uniform(0.5, 2.5, 2), rng.uniform(0, math.pi))
        probe = Obstacles([box])
        near = [probe.collides(np.array([p]), VEH, 1.2)[0] for p in (start, goal)]
        if not any(near) and not keep.collides_boxes(np.array([[cx, cy, 0.0]]), (-1.2, 1.2, -1.2, 1.2))[0]:
            polys.append(box)
    return Case(start=start, goal=goal, obstacles=tuple(polys))
