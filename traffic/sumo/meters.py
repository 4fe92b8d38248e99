"""Ramp-meter and route-guidance actuation in SUMO, as bus commands with ``apply_to_sumo(libsumo)``.

Controllers return these from ``step``; the SUMO backend applies them in the *act* phase, so no
controller calls libsumo to write.

Meter rates.  A beltway meter is a one-link traffic light ``meter_{d}{k}`` with a green phase and a
red phase (``corridor.traffic.networks.beltway``).  A rate r [veh/h] is realised as *one vehicle per green*: the cycle is
``3600 / r`` seconds, the green lasts ``green_s`` (about 2 s, enough for one vehicle to pass the stop
line) and the red the rest of the cycle.  The red never drops below ``min_red_s``, so the highest
metered rate is ``3600 / (green_s + min_red_s)``; a rate at or above ``open_rate_vph`` switches the
meter to SUMO's ``off`` program (no metering at all), and so does ``MeterOff``.

Route guidance.  Drivers of the beltway choose the outer (``ccw``) or inner (``cw``) loop at their
origin (routes ``od_{i}_{j}_{d}``).  Guidance moves the share of origin i's drivers on ``ccw`` from its
no-guidance value ``s0`` to a target ``s``: when ``s > s0`` each newly departed ``cw`` driver switches
with probability ``(s - s0) / (1 - s0)``, when ``s < s0`` each ``ccw`` driver with ``(s0 - s) / s0``
(``divert_probability``); a switched driver gets the route ``od_{i}_{j}_{other}`` via
``vehicle.setRouteID`` while it is still on its origin arterial (both routes share that edge).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

DIRECTIONS = ("ccw", "cw")
METERED_PROGRAM = "0"  # the beltway's metering program id
OFF_PROGRAM = "off"  # SUMO's built-in program: the signal is switched off (no metering)


@dataclass(frozen=True)
class MeterTiming:
    """How a rate is turned into green/red times."""

    green_s: float = 2.0  # [s] one vehicle per green
    min_red_s: float = 1.0  # [s] shortest red
    open_rate_vph: float = 1800.0  # [veh/h] at or above: meter switched off

    @property
    def max_metered_vph(self) -> float:
        """Highest rate a green/red cycle can realise [veh/h]."""
        return 3600.0 / (self.green_s + self.min_red_s)


def red_time_s(rate_vph: float, timing: MeterTiming = MeterTiming()) -> float:
    """Red time [s] of the cycle realising ``rate_vph`` with one vehicle per green."""
    if rate_vph <= 0.0:
        raise ValueError(f"meter rate must be > 0 veh/h, got {rate_vph}")
    return max(3600.0 / rate_vph - timing.green_s, timing.min_red_s)


def realised_rate_vph(rate_vph: float, timing: MeterTiming = MeterTiming()) -> float:
    """The rate [veh/h] the signal actually serves for a requested rate (inf when switched off)."""
    if rate_vph >= timing.open_rate_vph:
        return math.inf
    return 3600.0 / (timing.green_s + red_time_s(rate_vph, timing))


@dataclass(frozen=True)
class SetMeterRate:
    """Meter ``tls`` at ``rate_vph`` (one vehicle per green), or switch it off above the open rate."""

    tls: str
    rate_vph: float
    timing: MeterTiming = MeterTiming()

    def apply_to_sumo(self, libsumo: Any) -> None:
        tl = libsumo.trafficlight
        if self.rate_vph >= self.timing.open_rate_vph:
            MeterOff(self.tls).apply_to_sumo(libsumo)
            return
        red = red_time_s(self.rate_vph, self.timing)
        was_off = tl.getProgram(self.tls) == OFF_PROGRAM
        phase = 0 if was_off else tl.getPhase(self.tls)
        phases = [tl.Phase(self.timing.green_s, "G"), tl.Phase(red, "r")]
        tl.setProgramLogic(self.tls, tl.Logic(METERED_PROGRAM, 0, phase, phases))
        tl.setProgram(self.tls, METERED_PROGRAM)
        if not was_off and phase == 1:  # shorten or lengthen the running red to the new cycle
            tl.setPhaseDuration(self.tls, red)


@dataclass(frozen=True)
class MeterOff:
    """No control: the meter's signal is switched off (vehicles merge freely)."""

    tls: str

    def apply_to_sumo(self, libsumo: Any) -> None:
        libsumo.trafficlight.setProgram(self.tls, OFF_PROGRAM)


@dataclass(frozen=True)
class Reroute:
    """Give each vehicle a new named route: ``assignments`` = ((vehicle id, route id), ...).

    Vehicles that left the network (or left the shared first edge) since the decision are skipped.
    """

    assignments: tuple[tuple[str, str], ...]

    def apply_to_sumo(self, libsumo: Any) -> None:
        for vid, route in self.assignments:
            try:
                libsumo.vehicle.setRouteID(vid, route)
            except libsumo.TraCIException:
                continue


def parse_od_route(route_id: str) -> tuple[int, int, str] | None:
    """``od_{i}_{j}_{d}`` -> (i, j, d); None for any other route name."""
    parts = route_id.split("_")
    if len(parts) != 4 or parts[0] != "od" or parts[3] not in DIRECTIONS:
        return None
    return int(parts[1]), int(parts[2]), parts[3]


def other_direction(d: str) -> str:
    return "cw" if d == "ccw" else "ccw"


def divert_probability(default_share: float, target_share: float) -> tuple[str, float]:
    """(direction drivers are taken from, probability) that moves the ccw share from default to target.

    Both shares are of drivers on ``ccw`` [-]; the probability applies to each driver of the returned
    direction so that the expected ccw share becomes ``target_share``.
    """
    s0, s = float(np.clip(default_share, 0.0, 1.0)), float(np.clip(target_share, 0.0, 1.0))
    if s >= s0:
        return "cw", 0.0 if s0 >= 1.0 else (s - s0) / (1.0 - s0)
    return "ccw", (s0 - s) / s0


def loop_hops(i: int, j: int, n: int, d: str) -> int:
    """Interchanges passed from i to j on loop d of an n-interchange ring (ccw: k -> k+1)."""
    return (j - i) % n if d == "ccw" else (i - j) % n


@dataclass(frozen=True)
class ChoiceSet:
    """Which drivers route guidance may switch: only trips with a real choice of loop.

    A trip i -> j has a real choice when the other loop is at most ``max_extra_hops`` interchanges
    longer (0: only the ties, e.g. the opposite interchange); sending a short trip the long way round
    costs far more than it relieves.  ``movable[i] = (ccw, cw)`` are the shares of origin i's drivers
    that have a choice and drive ccw / cw by default: guidance can move the ccw share of origin i
    by at most these amounts.
    """

    n: int
    max_extra_hops: int
    movable: dict[int, tuple[float, float]]

    def has_choice(self, i: int, j: int) -> bool:
        cw, ccw = loop_hops(i, j, self.n, "cw"), loop_hops(i, j, self.n, "ccw")
        return abs(cw - ccw) <= self.max_extra_hops


def choice_set(od_dir_vph: dict[tuple[int, int, str], float], n: int, max_extra_hops: int = 0) -> ChoiceSet:
    """The ``ChoiceSet`` of a ring from its demand per (origin, destination, loop) [veh/h]."""
    probe = ChoiceSet(n, max_extra_hops, {})
    total, mov = np.zeros(n), np.zeros((n, 2))
    for (i, j, d), q in od_dir_vph.items():
        total[i] += q
        if probe.has_choice(i, j):
            mov[i, DIRECTIONS.index(d)] += q
    share = mov / np.maximum(total, 1e-12)[:, None]
    return ChoiceSet(n, max_extra_hops, {i: (float(share[i, 0]), float(share[i, 1])) for i in range(n)})


def guidance_assignments(new_vehicles: Iterable[tuple[str, str]], target_share: dict[int, float],
                         default_share: dict[int, float], rng: np.random.Generator,
                         choices: ChoiceSet | None = None) -> tuple[tuple[str, str], ...]:
    """Pick which newly departed vehicles switch loop: ((vid, new route id), ...).

    ``new_vehicles`` are (vehicle id, current route id); origins without a target keep their drivers.
    Without ``choices`` every driver of the giving loop may switch (``divert_probability``); with it
    only drivers with a real choice do, each with the probability that moves the origin's ccw share
    by the same amount (change / movable share of the giving loop, at most 1).
    """
    out: list[tuple[str, str]] = []
    for vid, route in new_vehicles:
        od = parse_od_route(route)
        if od is None or od[0] not in target_share:
            continue
        i, j, d = od
        s0 = default_share.get(i, 0.5)
        from_dir, p = divert_probability(s0, target_share[i])
        if choices is not None:
            if not choices.has_choice(i, j):
                continue
            movable = choices.movable.get(i, (0.0, 0.0))[DIRECTIONS.index(from_dir)]
            p = min(1.0, abs(float(target_share[i]) - s0) / movable) if movable > 0 else 0.0
        if d == from_dir and p > 0.0 and rng.random() < p:
            out.append((vid, f"od_{i}_{j}_{other_direction(d)}"))
    return tuple(out)
