"""``TrackedAgent``: another aircraft as the ego sees it through its link and tracker.

The MAVLink link (``corridor.vehicles.mavlink.air_link``) hands these to the UAV avoidance controllers; it is
a vehicle-side type, so the link does not import the controllers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TrackedAgent:
    """Another aircraft as the ego sees it through its link and tracker."""

    id: str
    pos: np.ndarray  # [m] ENU position estimate, shape (3,)
    vel: np.ndarray  # [m/s] ENU velocity estimate, shape (3,)
    sigma_m: float = 0.0  # [m] position uncertainty radius (e.g. 3 sigma of the track)
    is_piloted: bool = False  # piloted aircraft: UAVs give way
