"""Calibrate METANET's fundamental diagram from SUMO detector data of a ramp-metering scenario.

    python -m corridor.analysis.calibration scenarios/ramp_metering.yaml [--scale 1.1] [--seed 0]

Runs the scenario once without control (``ramp_none``: meters off) with its ``ramp_detectors``,
collects every mainline loop interval (up- and downstream of each merge) as a point
(density, flow, speed) per lane, and fits

    V(rho) = v_free exp(-(1/a) (rho / rho_crit)^a)          [km/h], rho [veh/km/lane]

to the (density, speed, flow) points with ``scipy.optimize.least_squares`` (bounded, soft-L1 loss
against outliers), on speed AND measured-flow residuals (rho V(rho) - q).  Loops report time-mean
speeds, which in stop-and-go traffic lie far above the space-mean speed q / rho (at 70 veh/km/lane:
~40 km/h against ~20), so a speed-only fit drags rho_crit far beyond the density of maximum flow
(62 instead of ~40 veh/km/lane on the beltway: an ALINEA set point of 31 % occupancy that the loops
rarely reach); the flow residuals pin rho_crit and the capacity to the top of the measured q(rho).  Density is occupancy x 10 / vehicle
length (SUMO loops report the share of time a vehicle body covers the loop).  Capacity per lane is
V(rho_crit) rho_crit = v_free rho_crit exp(-1/a).  The loops downstream of the merges (ALINEA's
feedback loops) are also fitted alone; their critical occupancy is stored as ``alinea_setpoint_pct``.
The result, the points and the fit error are stored beside the scenario as
``<name>.calibration.json``; ``ramp_mpc`` reads it when present.  The command above (in
``corridor.analysis.calibration``, since drawing is the report's job) also writes the fitted diagram
against the detector points as ``<name>.calibration.html``; ``run_scenario`` puts the same charts into
its report.
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

RHO_MAX_DEFAULT = 160.0  # [veh/km/lane] jam density (not identifiable from loop data; 1000/(l+gap))


@dataclass(frozen=True)
class FdFit:
    """Fitted fundamental diagram and how well it fits."""

    v_free_kmh: float
    rho_crit: float  # [veh/km/lane]
    a: float
    capacity_vph_per_lane: float
    rmse_kmh: float
    n_points: int

    def speed(self, rho: np.ndarray) -> np.ndarray:
        return self.v_free_kmh * np.exp(-(1.0 / self.a) * (np.asarray(rho) / self.rho_crit) ** self.a)


SPEED_SCALE_KMH = 5.0  # [km/h] speed residual worth one unit of the fit's loss
FLOW_SCALE_VPH = 100.0  # [veh/h/lane] flow residual worth one unit


def fit_fundamental_diagram(rho: np.ndarray, v_kmh: np.ndarray, v_free_guess: float = 100.0,
                            q_vph: np.ndarray | None = None) -> FdFit:
    """Least-squares fit of the METANET V(rho) to detector points (density [veh/km/lane], speed [km/h]).

    With the measured flows ``q_vph`` [veh/h/lane] the residuals are the speed error / 5 km/h and the
    flow error (rho V(rho) - q) / 100 veh/h/lane, so the fitted critical density sits at the top of the
    measured flow-density diagram; without them, speed only.
    """
    rho, v = np.asarray(rho, float), np.asarray(v_kmh, float)
    q = np.full_like(rho, np.nan) if q_vph is None else np.asarray(q_vph, float)
    ok = np.isfinite(rho) & np.isfinite(v) & (rho > 0)
    rho, v, q = rho[ok], v[ok], q[ok]
    if len(rho) < 5:
        raise ValueError(f"need at least 5 detector points with traffic, got {len(rho)}")
    has_q = q_vph is not None and bool(np.all(np.isfinite(q)))

    def speed(th: np.ndarray) -> np.ndarray:
        vf, rc, a = th
        return vf * np.exp(-(1.0 / a) * (rho / rc) ** a)

    def resid(th: np.ndarray) -> np.ndarray:
        vm = speed(th)
        if not has_q:
            return (vm - v) / SPEED_SCALE_KMH
        return np.concatenate([(vm - v) / SPEED_SCALE_KMH, (rho * vm - q) / FLOW_SCALE_VPH])

    x0 = np.array([max(v_free_guess, float(np.percentile(v, 95))), 30.0, 2.0])
    sol = least_squares(resid, x0, bounds=([30.0, 5.0, 0.5], [200.0, 120.0, 6.0]), loss="soft_l1", f_scale=3.0)
    vf, rc, a = (float(x) for x in sol.x)
    rmse = float(np.sqrt(np.mean((speed(sol.x) - v) ** 2)))
    return FdFit(vf, rc, a, vf * rc * math.exp(-1.0 / a), rmse, len(rho))


def detector_points(history: list[tuple[float, str, str, float, float, float]], lanes: int,
                    vehicle_length_m: float, side: str | None = None) -> dict[str, np.ndarray]:
    """Per-lane points from ``RampDetectors.history``: density [veh/km/lane], flow [veh/h/lane], speed.

    ``side`` = "up" or "down" keeps only the loops up- or downstream of the merges (None: all).
    """
    arr = [(occ, q, v) for _, _, s, occ, q, v in history
           if q > 0 and math.isfinite(v) and v >= 0 and side in (None, s)]
    if not arr:
        return {"rho": np.zeros(0), "q": np.zeros(0), "v_kmh": np.zeros(0)}
    occ, q, v = (np.asarray(c, float) for c in zip(*arr))
    return {"rho": occ * 10.0 / vehicle_length_m, "q": q / lanes, "v_kmh": v * 3.6}


def collect(scenario_path: Path, seed: int, scale: float, duration_s: float | None) -> tuple[Any, Any]:
    """Run the scenario once without metering; return (scenario, detectors component)."""
    from corridor.run import build
    from corridor.scenario import load

    sets = ["controllers={ramps: {type: ramp_none}}", f"road.demand.scale={scale}"]
    if duration_s is not None:
        sets.append(f"duration={duration_s}")
    sc, _ = load(scenario_path, sets)
    with tempfile.TemporaryDirectory(prefix="corridor-cal-") as tmp:
        sim = build(sc, seed, Path(tmp))
        sim.run()
    det = sim.provider("ramp_detectors")
    return sc, det


def calibrate(scenario_path: Path, seed: int = 0, scale: float = 1.0, duration_s: float | None = None,
              out: Path | None = None) -> Path:
    """Collect detector points, fit the diagram, write ``<scenario>.calibration.json``; returns its path."""
    from corridor.traffic.sumo.road_spec import road_spec

    sc, det = collect(scenario_path, seed, scale, duration_s)
    road = road_spec(sc)
    lanes = int(road.network.params.lanes)
    veh_len = float(next(iter(road.demand.vehicle_types.values())).length)
    pts = detector_points(det.history, lanes, veh_len)
    fit = fit_fundamental_diagram(pts["rho"], pts["v_kmh"],
                                  road.network.params.mainline_speed_mps * 3.6, q_vph=pts["q"])
    down = detector_points(det.history, lanes, veh_len, side="down")
    fit_down = fit_fundamental_diagram(down["rho"], down["v_kmh"], fit.v_free_kmh, q_vph=down["q"])
    out = out or scenario_path.with_suffix("").with_suffix(".calibration.json")
    doc = {"scenario": scenario_path.name, "seed": seed, "demand_scale": scale, "duration_s": sc.duration,
           "v_free_kmh": fit.v_free_kmh, "rho_crit": fit.rho_crit, "a": fit.a, "rho_max": RHO_MAX_DEFAULT,
           "capacity_vph_per_lane": fit.capacity_vph_per_lane, "rmse_kmh": fit.rmse_kmh,
           "n_points": fit.n_points, "vehicle_length_m": veh_len,
           # ALINEA's set point: the critical occupancy [%] of the loops it feeds back on (downstream of
           # the merges), from a fit of their points alone
           "alinea_setpoint_pct": fit_down.rho_crit * veh_len / 10.0,
           "downstream_fit": {"v_free_kmh": fit_down.v_free_kmh, "rho_crit": fit_down.rho_crit, "a": fit_down.a,
                              "capacity_vph_per_lane": fit_down.capacity_vph_per_lane,
                              "rmse_kmh": fit_down.rmse_kmh, "n_points": fit_down.n_points},
           "points": {k: [round(float(x), 3) for x in v] for k, v in pts.items()}}
    out.write_text(json.dumps(doc, indent=1))
    return out
