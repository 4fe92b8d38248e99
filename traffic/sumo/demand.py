"""Write SUMO route files (vehicle types, routes, flows) from plain data.

A flow's demand is a piecewise-linear profile of (time [s], rate [veh/h]) points.  It is cut into
consecutive ``<flow>`` elements of ``step_s`` seconds, each with the MEAN rate of the profile over its
step (the exact integral of the piecewise-linear profile divided by the step length), so the expected
number of vehicles equals the profile's integral.  Poisson arrivals use SUMO's
``period="exp(rate_per_s)"`` (exponential headways; ``periodType`` in SUMO 1.28's route.xsd); uniform
arrivals use ``number`` (evenly spaced, see ``_flow_elements``).  Steps without demand are skipped.  SUMO requires the flows of a route file sorted
by ``begin``, so all flows are sorted across FlowDefs.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from corridor.traffic.networks.registry import element, write_xml

MIN_RATE_VPH = 1e-9  # [veh/h] steps below this mean rate are treated as zero and skipped


@dataclass(frozen=True)
class VehicleTypeDef:
    """A SUMO ``<vType>``: ``attrs`` are SUMO attribute names (accel, decel, sigma, tau, lcCooperative...)."""

    id: str
    attrs: Mapping[str, str | float]


@dataclass(frozen=True)
class FlowDef:
    """Demand on one route: ``profile`` is [(t_s, veh_per_h), ...], piecewise linear in time."""

    id: str
    route: str
    vtype: str
    profile: Sequence[tuple[float, float]]
    depart_lane: str = "best"
    depart_speed: str = "max"
    arrivals: Literal["poisson", "uniform"] = "poisson"


def mean_rate_vph(profile: Sequence[tuple[float, float]], t0_s: float, t1_s: float) -> float:
    """Exact mean of the piecewise-linear profile over [t0, t1] [veh/h] (held constant outside it).

    A repeated time in the profile is a step (jump) in the rate.
    """
    times, rates = _profile_arrays(profile)
    return (_integral_to(times, rates, t1_s) - _integral_to(times, rates, t0_s)) / (t1_s - t0_s)


def _integral_to(times: np.ndarray, rates: np.ndarray, t_s: float) -> float:
    """Integral of the profile from its first time to ``t_s`` [veh/h * s] (negative before it)."""
    if t_s <= times[0]:
        return float(rates[0] * (t_s - times[0]))
    areas = 0.5 * (rates[1:] + rates[:-1]) * np.diff(times)
    i = int(np.searchsorted(times, t_s, side="right")) - 1  # last breakpoint at or before t
    done = float(np.sum(areas[:i]))
    if i == len(times) - 1:
        return done + float(rates[-1] * (t_s - times[-1]))
    rate_t = rates[i] + (rates[i + 1] - rates[i]) * (t_s - times[i]) / (times[i + 1] - times[i])
    return done + float(0.5 * (rates[i] + rate_t) * (t_s - times[i]))


def expected_count(profile: Sequence[tuple[float, float]], t0_s: float, t1_s: float) -> float:
    """Expected number of vehicles of the profile in [t0, t1]."""
    times, rates = _profile_arrays(profile)
    return (_integral_to(times, rates, t1_s) - _integral_to(times, rates, t0_s)) / 3600.0


def _profile_arrays(profile: Sequence[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Validated (times, rates) arrays of a profile."""
    arr = np.asarray(profile, dtype=float).reshape(-1, 2)
    if len(arr) == 0:
        raise ValueError("demand profile is empty")
    if np.any(np.diff(arr[:, 0]) < 0):
        raise ValueError("demand profile times must be non-decreasing")
    if np.any(arr[:, 1] < 0):
        raise ValueError("demand profile rates must be >= 0 veh/h")
    return arr[:, 0], arr[:, 1]


def _flow_elements(flow: FlowDef, end_s: float, step_s: float) -> list[tuple[float, str]]:
    """(begin, <flow> element) for every non-zero step of one FlowDef.

    Uniform arrivals use ``number`` = the step's share of the ROUNDED cumulative expected count, evenly
    spaced by SUMO, so the total never drifts by more than half a vehicle from the profile's integral
    (``vehsPerHour`` would add one vehicle per element, inserted at ``begin``).
    """
    out: list[tuple[float, str]] = []
    for k, t0 in enumerate(np.arange(0.0, end_s, step_s)):
        t1 = min(t0 + step_s, end_s)
        rate_vph = mean_rate_vph(flow.profile, t0, t1)
        if flow.arrivals == "poisson":
            law: dict[str, str | float] = {"period": f"exp({rate_vph / 3600.0:.9g})"}
            empty = rate_vph <= MIN_RATE_VPH
        else:
            number = round(expected_count(flow.profile, 0.0, t1)) - round(
                expected_count(flow.profile, 0.0, t0)
            )
            law, empty = {"number": str(number)}, number <= 0
        if empty:
            continue
        attrs: dict[str, str | float] = {
            "id": f"{flow.id}.{k}",
            "type": flow.vtype,
            "route": flow.route,
            "begin": float(t0),
            "end": float(t1),
            **law,
            "departLane": flow.depart_lane,
            "departSpeed": flow.depart_speed,
        }
        out.append((float(t0), element("flow", attrs)))
    return out


def write_routes(
    path: Path,
    routes: Mapping[str, Sequence[str]],
    vtypes: Sequence[VehicleTypeDef],
    flows: Sequence[FlowDef],
    end_s: float,
    step_s: float = 60.0,
    known_routes: Collection[str] = (),
) -> Path:
    """Write a SUMO routes file with ``vtypes``, named ``routes`` and stepwise ``flows`` up to ``end_s``
    (a flow may also use a route of ``known_routes``, declared by another route file of the run)."""
    if end_s <= 0 or step_s <= 0:
        raise ValueError(f"end_s ({end_s}) and step_s ({step_s}) must be > 0")
    for flow in flows:
        if flow.route not in routes and flow.route not in known_routes:
            raise ValueError(f"flow {flow.id!r}: unknown route {flow.route!r}")
        if flow.vtype not in {v.id for v in vtypes}:
            raise ValueError(f"flow {flow.id!r}: unknown vtype {flow.vtype!r}")
    items = [element("vType", {"id": v.id, **v.attrs}) for v in vtypes]
    items += [element("route", {"id": name, "edges": " ".join(edges)}) for name, edges in routes.items()]
    timed = [item for flow in flows for item in _flow_elements(flow, end_s, step_s)]
    items += [xml for _, xml in sorted(timed, key=lambda pair: pair[0])]  # stable: ties keep flow order
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_xml(Path(path), "routes", items)
