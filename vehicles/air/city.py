"""A city's delivery drones: vertiports, random delivery missions, a few piloted aircraft.

:class:`CitySpec` (a scenario's ``backends.<air>.params.city``) is drawn per run from the run's
generator (``air/city``): ``vertiports`` pads spread uniformly over a ``size_m`` x ``size_m`` square
around the origin (at least ``vertiport_spacing_m`` apart), ``n`` F450 quadcopters each on a
delivery from one vertiport to another, and ``piloted`` c172x crossing the square on straight
chords at ``piloted_alt_m`` (UAVs give way to them).

Operations are under way when the run starts: each drone starts at a uniform point of its first
leg (the first 90 %), redrawn (up to 30 rounds) while it is closer than ``start_spacing_m`` to
another. A drone cruises at its course's layer (quadrantal rule: ``alt_m + k
layer_step_m`` for course quadrant k, so crossing traffic is vertically separated) and counts as
arrived within ``arrive_radius_m`` of the pad's point at that layer; it then takes off for a new
destination drawn from ``air/missions`` at once (the fleet's density stays stationary).
:class:`Missions` holds every drone's current mission and the log of finished ones (struct of
arrays); the mission delay is the flown time minus the nominal time (distance to the arrival circle
/ cruise speed).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from corridor.vehicles.air.backend import AircraftSpec


class CitySpec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    n: int = Field(100, ge=2, le=50_000)  # [drones]
    size_m: float = Field(10_000.0, gt=100.0)  # [m] side of the square, centred on the origin
    vertiports: int = Field(100, ge=2, le=10_000)
    vertiport_spacing_m: float = Field(300.0, ge=0.0)  # [m] minimum distance between two pads
    start_spacing_m: float = Field(100.0, ge=0.0)  # [m] minimum 3-D distance between two drones at t = 0
    alt_m: float = Field(60.0, gt=10.0)  # [m] lowest cruise layer (ENU up)
    layer_step_m: float = Field(25.0, ge=0.0)  # [m] between the four course layers
    speed_mps: float = Field(7.0, gt=0.0)  # [m/s] cruise
    arrive_radius_m: float = Field(15.0, gt=0.0)  # [m] horizontal; vertical 10 m
    piloted: int = Field(2, ge=0, le=50)  # [aircraft] c172x crossing the city
    piloted_alt_m: float = Field(200.0, gt=30.0)  # [m]
    piloted_speed_mps: float = Field(50.0, gt=0.0)  # [m/s]


def _vertiports(spec: CitySpec, rng: np.random.Generator) -> np.ndarray:
    """(V, 2) pad positions [m]: uniform draws, rejecting those too close to an earlier pad."""
    half, out = 0.45 * spec.size_m, []
    for _ in range(200 * spec.vertiports):
        p = rng.uniform(-half, half, 2)
        if all(np.hypot(*(p - q)) >= spec.vertiport_spacing_m for q in out):
            out.append(p)
            if len(out) == spec.vertiports:
                return np.array(out)
    raise ValueError(f"city: cannot place {spec.vertiports} vertiports {spec.vertiport_spacing_m} m apart "
                     f"in {spec.size_m} m x {spec.size_m} m; lower vertiport_spacing_m")


def layer_alt(spec: CitySpec, course_rad: np.ndarray) -> np.ndarray:
    """Cruise altitude [m] of the course's quadrant (quadrantal rule)."""
    k = np.floor(np.mod(course_rad, 2.0 * np.pi) / (0.5 * np.pi)).astype(int) % 4
    return spec.alt_m + k * spec.layer_step_m


class Missions:
    """Every drone's current delivery (struct of arrays over the drones) and the finished ones."""

    def __init__(self, spec: CitySpec, pads: np.ndarray, rng: np.random.Generator) -> None:
        self.spec, self.pads, self.rng = spec, pads, rng
        n = spec.n
        self.dest = np.zeros(n, dtype=int)
        self.goal = np.zeros((n, 3))  # [m] ENU
        self.t_start = np.zeros(n)  # [s]
        self.nominal_s = np.zeros(n)  # [s]
        self.done_delay_s: list[np.ndarray] = []
        self.done_nominal_s: list[np.ndarray] = []

    def assign(self, rows: np.ndarray, t_s: float, pos: np.ndarray, origin_pad: np.ndarray) -> None:
        """New destinations for ``rows`` (at ``pos`` [m], leaving ``origin_pad``): any other pad."""
        v = len(self.pads)
        dest = (origin_pad + self.rng.integers(1, v, len(rows))) % v
        d = self.pads[dest] - pos[:, :2]
        course = np.arctan2(d[:, 1], d[:, 0])
        self.dest[rows] = dest
        self.goal[rows] = np.column_stack([self.pads[dest], layer_alt(self.spec, course)])
        self.t_start[rows] = t_s
        self.nominal_s[rows] = self.nominal(np.hypot(d[:, 0], d[:, 1]))

    def nominal(self, dist_m: np.ndarray) -> np.ndarray:
        """[s] nominal time of a delivery over ``dist_m`` [m]: to the arrival circle at cruise speed."""
        return np.maximum(dist_m - self.spec.arrive_radius_m, 0.0) / self.spec.speed_mps

    def arrivals(self, t_s: float, pos: np.ndarray) -> np.ndarray:
        """Rows that arrived (logged with their delay, and given the next delivery)."""
        d = self.goal - pos
        rows = np.flatnonzero((np.hypot(d[:, 0], d[:, 1]) < self.spec.arrive_radius_m) & (np.abs(d[:, 2]) < 10.0))
        if len(rows):
            self.done_delay_s.append(t_s - self.t_start[rows] - self.nominal_s[rows])
            self.done_nominal_s.append(self.nominal_s[rows].copy())
            self.assign(rows, t_s, pos[rows], self.dest[rows])
        return rows

    def delays(self) -> np.ndarray:
        """[s] delays of the finished deliveries."""
        return np.concatenate(self.done_delay_s) if self.done_delay_s else np.zeros(0)


def city_fleet(spec: CitySpec, rng: np.random.Generator, mission_rng: np.random.Generator
               ) -> tuple[list[AircraftSpec], Missions]:
    """The drones (ids ``d00000`` ...) and the piloted aircraft (``c172_0`` ...) of one run."""
    pads = _vertiports(spec, rng)
    n, v = spec.n, len(pads)
    a, b, frac = np.zeros(n, dtype=int), np.zeros(n, dtype=int), np.zeros(n)
    redraw = np.arange(n)
    for _ in range(30):
        k = len(redraw)
        a[redraw] = rng.integers(0, v, k)
        b[redraw] = (a[redraw] + rng.integers(1, v, k)) % v
        frac[redraw] = rng.uniform(0.0, 0.9, k)
        xy, course, start = _starts(spec, pads, a, b, frac)
        pairs = cKDTree(start).query_pairs(spec.start_spacing_m, output_type="ndarray")
        redraw = np.unique(pairs[:, 1])
        if len(redraw) == 0:
            break
    missions = Missions(spec, pads, mission_rng)
    missions.dest = b
    missions.goal = np.column_stack([pads[b], start[:, 2]])
    missions.nominal_s = missions.nominal(np.hypot(*(pads[b] - xy).T))
    out = [AircraftSpec(id=f"d{k:05d}", start_enu=tuple(start[k].tolist()), yaw_deg=float(np.degrees(course[k])),
                        cruise_speed_mps=spec.speed_mps, goal_enu=tuple(missions.goal[k].tolist()))
           for k in range(n)]
    return out + _piloted(spec, rng), missions


def _starts(spec: CitySpec, pads: np.ndarray, a: np.ndarray, b: np.ndarray, frac: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start xy [m], course [rad] and ENU start [m] of drones ``frac`` along pad a -> pad b."""
    xy = pads[a] + frac[:, None] * (pads[b] - pads[a])
    course = np.arctan2(*(pads[b] - pads[a])[:, ::-1].T)
    return xy, course, np.column_stack([xy, layer_alt(spec, course)])


def _piloted(spec: CitySpec, rng: np.random.Generator) -> list[AircraftSpec]:
    """c172x on straight chords: from a random point of the square's edge through a random inner point."""
    half, out = 0.5 * spec.size_m, []
    for k in range(spec.piloted):
        side, s = rng.integers(0, 4), rng.uniform(-half, half)
        start = [(-half, s), (half, s), (s, -half), (s, half)][side]
        through = rng.uniform(-0.5 * half, 0.5 * half, 2)
        u = (through - np.array(start)) / np.linalg.norm(through - np.array(start))
        end = np.array(start) + u * 4.0 * spec.size_m
        yaw = float(np.degrees(np.arctan2(u[1], u[0])))
        out.append(AircraftSpec(id=f"c172_{k}", model="c172x", start_enu=(*map(float, start), spec.piloted_alt_m),
                                yaw_deg=yaw, speed_mps=spec.piloted_speed_mps, cruise_speed_mps=spec.piloted_speed_mps,
                                waypoints_enu=[(*map(float, end), spec.piloted_alt_m)], role="piloted"))
    return out
