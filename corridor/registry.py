"""Register components by name (Gymnasium style): a scenario says ``type: alinea`` and the registry
finds the class.  Entries are ``"module:Attr"`` strings imported lazily, so loading a scenario does not
import CasADi or JSBSim unless the scenario uses them.  Adding a controller is one file and one line.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Entry:
    name: str
    entry_point: str  # "package.module:Attr"

    def load(self) -> Any:
        module, _, attr = self.entry_point.partition(":")
        return getattr(importlib.import_module(module), attr)


class Registry:
    """A named table of lazily imported entry points."""

    def __init__(self, what: str) -> None:
        self.what = what
        self._entries: dict[str, Entry] = {}

    def register(self, name: str, entry_point: str) -> None:
        if name in self._entries and self._entries[name].entry_point != entry_point:
            raise ValueError(f"{self.what} {name!r} is already registered")
        self._entries[name] = Entry(name, entry_point)

    def get(self, name: str) -> Any:
        try:
            return self._entries[name].load()
        except KeyError:
            raise KeyError(f"unknown {self.what} {name!r}; known: {', '.join(sorted(self))}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)


# The component tables of corridor.  Each entry point is a class with a nested pydantic ``Params``
# model (validated at scenario load) and a constructor ``cls(name, params, scenario)``.
BACKENDS = Registry("backend")
CONTROLLERS = Registry("controller")
MONITORS = Registry("monitor")

CONTROLLERS.register("none", "corridor.engine:NoController")
CONTROLLERS.register("v2x_merging", "corridor.controllers.v2x_merging:V2XMerging")

MONITORS.register("collisions", "corridor.analysis.monitors:CollisionMonitor")
MONITORS.register("surrogate_safety", "corridor.traffic.monitors:SurrogateSafety")
MONITORS.register("traffic_kpis", "corridor.traffic.monitors:TrafficKpis")
MONITORS.register("trips", "corridor.traffic.trips:Trips")

BACKENDS.register("jsbsim_fleet", "corridor.vehicles.air_backend:AirBackend")
BACKENDS.register("mavlink_link", "corridor.vehicles.air_link:AirLink")
CONTROLLERS.register("uav_none", "corridor.controllers.uav_avoidance:UavNone")
CONTROLLERS.register("potential_field", "corridor.controllers.uav_avoidance:PotentialFieldController")
CONTROLLERS.register("control_tube", "corridor.controllers.uav_avoidance:ControlTubeController")
MONITORS.register("uav_separation", "corridor.analysis.separation:SeparationMonitor")
CONTROLLERS.register("ramp_none", "corridor.controllers.ramp_control:RampNone")
CONTROLLERS.register("ramp_alinea", "corridor.controllers.ramp_control:RampAlinea")
CONTROLLERS.register("ramp_mpc", "corridor.controllers.ramp_control:RampMpc")
MONITORS.register("ramp_detectors", "corridor.traffic.detectors:RampDetectors")
MONITORS.register("ramp_kpis", "corridor.traffic.ramp_monitors:RampKpis")
BACKENDS.register("ego_bicycle", "corridor.vehicles.ego_bicycle:EgoBicycle")
CONTROLLERS.register("overtaking", "corridor.controllers.overtaking_sumo:OvertakingSumo")
CONTROLLERS.register("ramp_fixed", "corridor.controllers.ramp_control:RampFixed")
BACKENDS.register("metanet", "corridor.controllers.metanet_backend:MetanetBackend")
CONTROLLERS.register("metanet_none", "corridor.controllers.metanet_backend:MetanetNone")
CONTROLLERS.register("metanet_alinea", "corridor.controllers.metanet_backend:MetanetAlinea")
CONTROLLERS.register("metanet_mpc", "corridor.controllers.metanet_backend:MetanetMpc")
