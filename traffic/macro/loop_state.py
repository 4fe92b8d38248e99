"""Loop-station readings as METANET state: the traffic centre's side of the ramp MPC.

The beltway's loop stations (``corridor.traffic.sensing.detectors``) report occupancy, flow and time-mean
speed per interval; the MPC's METANET model wants density and space-mean speed per segment.  This
module holds that mapping (``estimate_state``, the direct mapping without a filter, and
``loop_speed_kmh``, the space-mean speed of one station) and the data files it is calibrated with:
the fundamental-diagram fit (``load_calibration``; written by ``corridor.traffic.macro.calibrate``) and the
station map (``load_station_map``; ``corridor.traffic.macro.station_map``).  The segment fusion
(``corridor.traffic.macro.fusion_component``) and the ``ramp_mpc`` controller both use it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from corridor.traffic.sensing.detectors import RampMeasurement

SUMO_DIR_OF_MODEL = ("ccw", "cw")  # METANET direction 0 runs k -> k+1 (SUMO "ccw"), 1 runs k -> k-1
RHO_FLOOR = 0.1  # [veh/km/lane] lowest density handed to the MPC (empty loops at the start)
DEFAULT_FD = {"v_free_kmh": 100.0, "rho_crit": 28.0, "a": 1.867, "rho_max": 160.0}  # before calibration


def load_calibration(name: str | None) -> dict[str, float]:
    """Fundamental-diagram parameters from a calibration JSON (``corridor.traffic.macro.calibrate``).

    A relative name is looked up in the working directory, its ``scenarios/`` folder and the
    repository's ``scenarios/`` folder; missing file -> the defaults of ``DEFAULT_FD``.
    """
    import json

    out = dict(DEFAULT_FD)
    if not name:
        return out
    cand = scenario_data_file(name)
    if cand is not None:
        fit = json.loads(cand.read_text())
        out.update({k: float(fit[k]) for k in (*DEFAULT_FD, "alinea_setpoint_pct") if k in fit})
        out["source"] = str(cand)  # type: ignore[assignment]
    return out


def scenario_data_file(name: str) -> Any:
    """A data file beside the scenarios (calibration, station map): ``name`` as given, under
    ``scenarios/`` of the working directory or of the repository / installed package; None if absent."""
    from pathlib import Path

    packaged = [Path(__file__).resolve().parents[2] / "scenarios"]  # a checkout: <repo>/scenarios
    try:
        import corridor.scenarios as pkg  # an installed wheel: scenarios ship as package data

        packaged += [Path(p) for p in pkg.__path__]
    except ImportError:
        pass
    for cand in (Path(name), Path("scenarios") / name, *(d / name for d in packaged)):
        if cand.is_file():
            return cand
    return None


RHO_SPACE_MEAN_MIN = 5.0  # [veh/km/lane] below: loop speed (q / rho too noisy in light traffic)


def loop_speed_kmh(occ_pct: float, flow_vph: float, speed_mps: float, lanes: int | None,
                   vehicle_length_m: float) -> float:
    """Space-mean speed [km/h] of a loop group: q / rho, at most the loops' time-mean speed.

    Loops report time-mean speeds, which in stop-and-go traffic lie far above the space-mean speed
    that METANET's q = rho v needs (at 70 veh/km/lane ~40 against ~20 km/h on the beltway), so with
    the flow [veh/h, all lanes] and density from occupancy the identity q / rho is used instead
    (space-mean <= time-mean speed).  nan when nobody passed; the loop speed in light traffic or
    without ``lanes``.
    """
    v_loop = 3.6 * speed_mps
    rho = occ_pct * 10.0 / vehicle_length_m
    if lanes is None or not math.isfinite(v_loop) or flow_vph <= 0.0 or rho < RHO_SPACE_MEAN_MIN:
        return v_loop
    return min(v_loop, flow_vph / lanes / rho)


def estimate_state(net: Any, ramps: dict[str, RampMeasurement], n: int, m: int,
                   vehicle_length_m: float, lanes: int | None = None) -> np.ndarray:
    """METANET state from the detectors by a direct mapping (no filter).

    Density [veh/km/lane] = occupancy [%] x 10 / vehicle length [m] and speed [km/h] of the loops just
    downstream of merge k and just upstream of the next merge, interpolated linearly over the m
    segments of the link between them (a missing speed takes the equilibrium speed of the density).
    With ``lanes`` the speed is the space-mean speed q / rho of each loop group (``loop_speed_kmh``).
    Queues are the vehicles on each on-ramp storage (E2).  Densities are floored at ``RHO_FLOOR``: at
    rho = 0 the derivative of (rho/rho_crit)^a is NaN in CasADi and IPOPT stops at once.
    """
    from corridor.traffic.macro.metanet import equilibrium_speed

    rho, v = np.zeros(net.n_seg), np.zeros(net.n_seg)
    for dirn, d in enumerate(SUMO_DIR_OF_MODEL):
        hop = 1 if dirn == 0 else -1
        for k in range(n):
            a, b = ramps[f"{d}{k}"], ramps[f"{d}{(k + hop) % n}"]
            for s in range(m):
                f = (s + 0.5) / m
                i = (dirn * n + k) * m + s
                rho[i] = ((1 - f) * a.occupancy_down_pct + f * b.occupancy_up_pct) * 10.0 / vehicle_length_m
                speeds = [x for x in (
                    loop_speed_kmh(a.occupancy_down_pct, a.flow_down_vph, a.speed_down_mps, lanes, vehicle_length_m),
                    loop_speed_kmh(b.occupancy_up_pct, b.flow_up_vph, b.speed_up_mps, lanes, vehicle_length_m),
                ) if math.isfinite(x)]
                v[i] = float(np.mean(speeds)) if speeds else math.nan
    rho = np.maximum(rho, RHO_FLOOR)
    v_eq = equilibrium_speed(rho, net.v_free_kmh, net.rho_crit, net.a)
    v = np.where(np.isfinite(v), v, v_eq)
    w = np.array([ramps[f"{SUMO_DIR_OF_MODEL[j % 2]}{j // 2}"].queue_veh for j in range(net.n_orig)])
    return np.concatenate([rho, v, w])


def load_station_map(name: str) -> Any:
    """The ``StationMap`` in data file ``name`` (see ``scenario_data_file``); a missing file is an error."""
    from corridor.traffic.macro.station_map import StationMap

    path = scenario_data_file(name)
    if path is None:
        raise ValueError(f"station_map: no file {name!r} (looked in ., scenarios/ and the packaged scenarios)")
    return StationMap.load(path)
