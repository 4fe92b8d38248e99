"""Named driver presets for SUMO vehicle types (``road.demand.vehicle_types.<t>.preset``).

A preset is a set of ``VehicleTypeSpec`` field values (car-following model and parameters, lane-change
attributes in ``lc``, other vType attributes in ``extra``).  A vehicle type that names a preset takes
its values as defaults; the fields the scenario gives beside it override them (``lc`` and ``extra``
key by key).  SUMO attribute names are those of SUMO 1.28's schema (``data/xsd/types/route.xsd``).

How the human presets were chosen (published targets only, before any V2X comparison) is logged in
``docs/guide/merging-calibration.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# SUMO's own passenger car: Krauss with its defaults and LC2013 with its defaults (no lc overrides)
SUMO_DEFAULT: dict[str, Any] = {
    "car_following": "Krauss", "accel": 2.6, "decel": 4.5, "emergency_decel": 9.0, "sigma": 0.5, "tau": 1.0,
    "length": 5.0, "min_gap": 2.5, "speed_dev": 0.1,
}

# Flow's human driver (flow.core.params.SumoCarFollowingParams defaults, speed mode "obey_safe_speed")
FLOW_HUMAN: dict[str, Any] = {
    "car_following": "IDM", "accel": 2.6, "decel": 4.5, "sigma": 0.5, "tau": 1.0, "length": 5.0,
    "min_gap": 2.5, "max_speed": 30.0, "speed_factor": 1.0, "speed_dev": 0.1, "extra": {"impatience": 0.5},
    "speed_mode": 1,
}

# Candidates of the human-driver calibration (docs/guide/merging-calibration.md, section 3)
IDM_TK: dict[str, Any] = {  # IDM, Treiber & Kesting's highway values, no noise
    "car_following": "IDM", "accel": 1.0, "decel": 1.5, "emergency_decel": 9.0, "tau": 1.0, "length": 5.0,
    "min_gap": 2.0, "speed_dev": 0.1, "extra": {"delta": 4},
}
EIDM_HUMAN: dict[str, Any] = {  # EIDM with its own driver errors and reaction (SUMO's EIDM defaults)
    "car_following": "EIDM", "accel": 1.5, "decel": 2.0, "emergency_decel": 9.0, "tau": 1.2, "length": 5.0,
    "min_gap": 2.0, "speed_dev": 0.1,
}
EIDM_MERGE: dict[str, Any] = {  # ... plus less cooperative, more assertive merging and a start-up delay
    **EIDM_HUMAN, "lc": {"lcCooperative": 0.5, "lcAssertive": 1.3, "lcSigma": 0.2},
    "extra": {"startupDelay": 0.8},
}
KRAUSS_HUMAN: dict[str, Any] = {  # Krauss with human acceleration, headway and start-up delay
    "car_following": "Krauss", "accel": 1.5, "decel": 2.0, "emergency_decel": 9.0, "sigma": 0.5, "tau": 1.2,
    "length": 5.0, "min_gap": 2.0, "speed_dev": 0.1,
    "lc": {"lcCooperative": 0.5, "lcAssertive": 1.3, "lcSigma": 0.2}, "extra": {"startupDelay": 0.8},
}

PRESETS: dict[str, dict[str, Any]] = {
    "sumo_default": SUMO_DEFAULT,
    "human_merge": EIDM_HUMAN,  # the calibrated humans: chosen 2026-11-26 16:57 UTC from the published
    #   targets alone (capacity drop 11.5 % [7.4, 15.6] over 7 seeds; docs/guide/merging-calibration.md)
    "flow_human": FLOW_HUMAN,
    "idm_tk": IDM_TK,
    "eidm_human": EIDM_HUMAN,
    "eidm_merge": EIDM_MERGE,
    "krauss_human": KRAUSS_HUMAN,
}


def preset_values(name: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """The preset's values overridden by ``given`` (the type's own fields; ``preset`` kept)."""
    if name not in PRESETS:
        raise ValueError(f"unknown driver preset {name!r}; known: {', '.join(sorted(PRESETS))}")
    base = PRESETS[name]
    out = {**base, **given}
    for key in ("lc", "extra"):
        if key in base or key in given:
            out[key] = {**base.get(key, {}), **(given.get(key) or {})}
    return out
