"""Ramp-metering controllers for the SUMO beltway: ``ramp_none``, ``ramp_alinea`` and ``ramp_mpc``
(and ``ramp_fixed``, every meter at one rate).

All three read the ``ramp_detectors`` peer (loops, ramp queues) and return meter commands of
``corridor.traffic.sumo.meters`` (applied by the SUMO backend).  They tick every ``tick_s`` (a few
seconds, so route guidance catches drivers while they are on their origin arterial) and decide new
rates every ``control_step_s`` (60 s).

* ``ramp_none``: every meter switched off (SUMO's ``off`` program), no guidance.
* ``ramp_alinea``: one ALINEA per ramp on the occupancy downstream of its merge (``Alinea``, gain
  ~70 veh/h per %, set point near critical occupancy) with the queue override that keeps each ramp
  queue under its storage; no guidance.
* ``ramp_mpc``: the coordinated ramp-metering + route-guidance MPC (``RampMeteringMPC``) on a
  METANET model of the same ring (``MetanetBeltway``); state from the detectors by a direct mapping
  (see ``estimate_state``); a solver failure falls back to ALINEA for that step and is logged as a
  ``fallback`` event and counted.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.controllers.ramp_metering.alinea import Alinea, AlineaConfig
from corridor.engine import Controller, Need, RunContext
from corridor.traffic.macro.loop_state import (
    RHO_FLOOR,
    SUMO_DIR_OF_MODEL,
    estimate_state,
    load_calibration,
    load_station_map,
)
from corridor.traffic.networks.landmarks import BeltwayLandmarks
from corridor.traffic.sensing.detectors import NEEDS_DETECTORS, RampDetectors, RampMeasurement
from corridor.traffic.sumo.meters import (
    ChoiceSet,
    MeterOff,
    MeterTiming,
    Reroute,
    SetMeterRate,
    choice_set,
    guidance_assignments,
    parse_od_route,
)
from corridor.traffic.sumo.road_spec import require_landmarks, road_spec
from corridor.traffic.sumo.trips import road_frame


class RampParams(BaseModel):
    """Settings shared by the ramp controllers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    tick_s: float = Field(5.0, gt=0)  # [s] controller tick (guidance); a multiple of dt
    control_step_s: float = Field(60.0, gt=0)  # [s] between metering decisions
    green_s: float = Field(2.0, gt=0)  # [s] one vehicle per green
    min_red_s: float = Field(1.0, gt=0)  # [s]
    open_rate_vph: float = Field(1800.0, gt=0)  # [veh/h] at or above: meter off
    rate_min_vph: float = Field(240.0, ge=0)  # [veh/h]
    alinea_gain_vph_per_pct: float = Field(70.0, gt=0)  # K_R
    # ALINEA set point [%]; None: the calibrated critical occupancy of the downstream loops
    # (``setpoint_from_calibration``)
    alinea_setpoint_pct: float | None = Field(None, gt=0)
    override_frac: float = Field(0.7, gt=0, le=1)  # queue override at this share of storage
    vehicle_length_m: float = Field(5.0, gt=0)  # occupancy <-> density: rho = occ[%] 10 / length
    calibration_file: str | None = "ramp_metering.calibration.json"  # FD fit; see ``load_calibration``

    @model_validator(mode="after")
    def _rate_range(self) -> RampParams:
        if self.rate_min_vph > self.open_rate_vph:
            raise ValueError(f"rate_min_vph ({self.rate_min_vph:g} veh/h) must not exceed open_rate_vph "
                             f"({self.open_rate_vph:g} veh/h)")
        return self


@dataclass
class RampObservation:
    """What a ramp controller sees at one tick."""

    t: float  # [s]
    ramps: dict[str, RampMeasurement]
    new_on_origin: dict[int, list[tuple[str, str]]] = field(default_factory=dict)  # (vid, route id)


class RampControl(Controller):
    """Common engine glue: observe the detectors, decide every control step (the ``ramp_meters``
    monitor records the rates the meters run, from these commands)."""

    Params = RampParams
    needs: ClassVar[dict[str, Need]] = {"det": NEEDS_DETECTORS}
    period_source: ClassVar[str | None] = "p.tick_s"
    det: RampDetectors

    @classmethod
    def check_scenario(cls, params: RampParams, scenario: Any) -> None:
        """At load: the road's network must have metered on-ramps and their detectors."""
        require_landmarks(scenario, BeltwayLandmarks, "ramp metering")

    def __init__(self, name: str, params: RampParams | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.scenario = scenario
        self.timing = MeterTiming(self.p.green_s, self.p.min_red_s, self.p.open_rate_vph)
        self.rates_vph: dict[str, float] = {}
        self._next_control_s = 0.0
        self._ctx: RunContext | None = None

    def setup(self, ctx: RunContext) -> None:
        self._ctx = ctx
        super().setup(ctx)

    def observe(self, ctx: RunContext) -> RampObservation:
        tb = road_frame(ctx).tables
        uid_of, route, names = tb.uid_of, tb.route, tb.route_names
        fresh = {k: [(v, names[route[uid_of[v]]] if v in uid_of else "") for v in vids]
                 for k, vids in self.det.new_on_origin.items()}
        return RampObservation(t=ctx.t, ramps=self.det.latest, new_on_origin=fresh)

    def step(self, obs: RampObservation) -> list[Any]:
        cmds: list[Any] = self.guide(obs)
        if obs.t + 1e-9 < self._next_control_s:
            return cmds
        self._next_control_s += self.p.control_step_s
        new = self.decide(obs)
        for key, rate in new.items():
            if key not in self.rates_vph or abs(self.rates_vph[key] - rate) > 1.0:
                cmds.append(self.meter_command(obs.ramps[key].tls, rate))
            self.rates_vph[key] = rate
        return cmds

    def meter_command(self, tls: str, rate_vph: float) -> Any:
        return SetMeterRate(tls, rate_vph, self.timing)

    def decide(self, obs: RampObservation) -> dict[str, float]:
        """New rate [veh/h] per ramp key (>= open rate: meter off)."""
        return {key: math.inf for key in obs.ramps}

    def guide(self, obs: RampObservation) -> list[Any]:
        """Route-guidance commands for this tick (none by default)."""
        return []


class RampNone(RampControl):
    """No control: meters off from the first tick on."""

    def meter_command(self, tls: str, rate_vph: float) -> Any:
        return MeterOff(tls)


class FixedParams(RampParams):
    fixed_rate_vph: float = Field(600.0, gt=0)  # [veh/h] every meter (>= open_rate_vph: off)


class RampFixed(RampControl):
    """Every meter at one fixed rate (a baseline and a check that a meter really limits ramp flow)."""

    Params = FixedParams

    def decide(self, obs: RampObservation) -> dict[str, float]:
        return {key: self.p.fixed_rate_vph for key in obs.ramps}


class RampAlinea(RampControl):
    """ALINEA with queue override on every ramp (local feedback, no coordination, no guidance)."""

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.alineas: dict[str, Alinea] = {}
        self.setpoint_pct = setpoint_from_calibration(self.p)

    def _alinea(self, m: RampMeasurement) -> Alinea:
        if m.key not in self.alineas:
            p = self.p
            self.alineas[m.key] = Alinea(AlineaConfig(
                gain_vph_per_pct=p.alinea_gain_vph_per_pct, setpoint_pct=self.setpoint_pct,
                rate_min_vph=p.rate_min_vph, rate_max_vph=p.open_rate_vph, storage_veh=m.storage_veh,
                override_frac=p.override_frac, period_s=p.control_step_s))
        return self.alineas[m.key]

    def decide(self, obs: RampObservation) -> dict[str, float]:
        return {key: self._alinea(m).step(m.occupancy_down_pct, m.queue_veh, m.demand_vph)
                for key, m in obs.ramps.items()}



# ---------------------------------------------------------------------------------------------------
# MPC: coordinated ramp metering + route guidance on METANET


class RampMpcParams(RampParams):
    """Settings of ``ramp_mpc`` (besides the shared ones)."""

    horizon_ctrl_steps: int = Field(4, ge=1, le=30)  # [control steps] 4 x 60 s (30: half an hour)
    model_step_s: float = Field(20.0, gt=0)  # [s] METANET step (3 per control step; shorter: p95 > 2 s here)
    seg_target_km: float = Field(1.25, gt=0)  # [km] target METANET segment length
    weight_rate_change: float = Field(0.4, ge=0)
    weight_split_change: float = Field(0.4, ge=0)
    compliance: float = Field(1.0, ge=0, le=1)  # share of drivers with a real choice who follow guidance
    guidance_extra_hops: int = Field(0, ge=0, le=16)  # [interchanges] a trip has a choice if the other loop is <= this longer
    storage_frac: float = Field(0.8, gt=0, le=1)  # MPC queue limit = this x ramp storage
    # The solve budget is IPOPT's iteration count, so the same seed gives the same rows on any load:
    # beyond it the last iterate if feasible and better than holding the rates, else ALINEA.  The
    # beltway's solves take 10-500 iterations (~5 ms each here; air_ground_watch loops_failed, seed
    # 0, 900 s: median 84, max 491), so 500 ends practically none of them early.
    max_iter: int = Field(500, ge=1, le=10000)
    # CPU-time safety net per solve [s] (at most 10 min), far above a 500-iteration solve (~2.5 s);
    # a solve it ends is logged (event ``mpc_cpu_cap``) and counted (``mpc_cpu_capped``), since the
    # run then depends on the machine's load.  (It used to be the budget, 1.5 s: under load the MPC
    # fell back to ALINEA on up to half of its steps, and rows differed between identical runs.)
    max_cpu_time_s: float = Field(60.0, gt=0, le=600)
    guidance: bool = True
    # name of a ``segment_estimate`` component (``segment_fusion``: loops + UAV cameras) the MPC takes
    # its density/speed state from; None: the loops by the direct mapping (``estimate_state``)
    estimator: str | None = None
    # with an estimator: the file of the map from segment-mean density (what the estimator estimates) to
    # the station scale the model is calibrated on (``corridor.traffic.macro.station_map``); None: identity
    station_map: str | None = None


def setpoint_from_calibration(p: RampParams) -> float:
    """ALINEA set point [%]: the given one, else the calibrated critical occupancy.

    The calibration's ``alinea_setpoint_pct`` is the critical occupancy of the loops ALINEA feeds back
    on (downstream of the merges, fitted alone); older files without it give the ring diagram's
    rho_crit [veh/km/lane] x vehicle length [m] / 10 (SUMO loops report the share of time a vehicle
    body covers them); without a calibration file ``DEFAULT_FD`` is used.
    """
    if p.alinea_setpoint_pct is not None:
        return float(p.alinea_setpoint_pct)
    fd = load_calibration(p.calibration_file)
    if "alinea_setpoint_pct" in fd:
        return float(fd["alinea_setpoint_pct"])
    return float(fd["rho_crit"]) * p.vehicle_length_m / 10.0


def od_matrix(flows: dict[str, Any], n: int) -> np.ndarray:
    """OD matrix [veh/h] (mean rate of each od_{i}_{j}_{d} flow over its profile, both loops summed)."""
    od = np.zeros((n, n))
    for fl in flows.values():
        parsed = parse_od_route(fl.route)
        if parsed is None:
            continue
        prof = np.asarray(fl.rate_profile(1.0, 1.0), dtype=float)
        od[parsed[0], parsed[1]] += float(prof[:, 1].mean())
    return od


def od_by_loop(flows: dict[str, Any]) -> dict[tuple[int, int, str], float]:
    """Mean rate [veh/h] of every od_{i}_{j}_{d} flow, keyed (i, j, d)."""
    out: dict[tuple[int, int, str], float] = {}
    for fl in flows.values():
        parsed = parse_od_route(fl.route)
        if parsed is not None:
            prof = np.asarray(fl.rate_profile(1.0, 1.0), dtype=float)
            out[parsed] = out.get(parsed, 0.0) + float(prof[:, 1].mean())
    return out


def with_guidance_bounds(net: Any, choices: ChoiceSet, compliance: float) -> Any:
    """The network with split bounds only guidance can reach: s0 - c e_ccw <= s <= s0 + c e_cw.

    The model's split is the share of an origin's drivers on direction 0 (SUMO ``ccw``); guidance
    moves only drivers with a real choice (``choices``), and only the complying share c of them.
    """
    mov = np.array([choices.movable.get(k, (0.0, 0.0)) for k in range(len(net.split_default))])
    lo = np.clip(net.split_default - compliance * mov[:, 0], 0.0, 1.0)
    hi = np.clip(net.split_default + compliance * mov[:, 1], 0.0, 1.0)
    return dataclasses.replace(net, split_lo=lo, split_hi=hi)


class DemandForecast:
    """Expected arterial demand of each interchange [veh/h] from the scenario's flow profiles.

    The MPC is given the demand profile the scenario declares (the expected demand; the realised
    arrivals are random), like the perfect forecast of Hegyi et al. (2005).
    """

    def __init__(self, scenario: Any, n: int) -> None:
        d = road_spec(scenario).demand
        self.profiles: list[tuple[int, np.ndarray]] = []
        for fl in d.flows.values():
            parsed = parse_od_route(fl.route)
            if parsed is not None:
                self.profiles.append((parsed[0], np.asarray(fl.rate_profile(scenario.duration, d.scale), float)))
        self.n = n

    def __call__(self, times_s: np.ndarray) -> np.ndarray:
        """(len(times), n) demand per interchange."""
        out = np.zeros((len(times_s), self.n))
        for i, prof in self.profiles:
            out[:, i] += np.interp(times_s, prof[:, 0], prof[:, 1])
        return out


class RampMpc(RampControl):
    """Coordinated ramp metering + route guidance by METANET MPC, ALINEA fallback on solver failure."""

    Params = RampMpcParams
    needs: ClassVar[dict[str, Need]] = {**RampControl.needs,
                                        "fusion": Need(role="segment_estimate", name_at="p.estimator", optional=True)}
    fusion: Any = None

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        self._build(ctx)

    def _build(self, ctx: RunContext) -> None:
        from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
        from corridor.traffic.macro.metanet import MetanetParams
        from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway

        p, lm = self.p, road_frame(ctx).tables.landmarks
        self.n = n = len(lm.interchanges)
        fd = self.fd = load_calibration(p.calibration_file)
        ring_km = float(np.mean(list(lm.ring_length_m.values()))) / 1000.0
        storage = float(lm.interchanges[0].ccw.ramp_storage_veh) * p.storage_frac
        layout = BeltwayLayout(n_interchanges=n, spacing_km=ring_km / n, seg_target_km=p.seg_target_km,
                               lanes=int(lm.lanes), v_free_kmh=fd["v_free_kmh"], rho_crit=fd["rho_crit"],
                               a=fd["a"], rho_max=fd["rho_max"], ramp_cap_vph=p.open_rate_vph,
                               ramp_storage_veh=storage, compliance=0.0)
        sc = ctx.scenario
        flows = road_spec(sc).demand.flows
        self.choices = choice_set(od_by_loop(flows), n, p.guidance_extra_hops)
        net = beltway(layout, od_matrix(flows, n), MetanetParams(step_h=p.model_step_s / 3600.0))
        self.net = with_guidance_bounds(net, self.choices, p.compliance if p.guidance else 0.0)
        self.m_seg = self.net.n_seg // (2 * n)
        self.lanes = int(lm.lanes)
        cfg = MPCConfig(horizon_ctrl_steps=p.horizon_ctrl_steps, control_step_s=p.control_step_s,
                        weight_rate_change=p.weight_rate_change, weight_split_change=p.weight_split_change,
                        rate_min=p.rate_min_vph / p.open_rate_vph, rate_max=1.0,
                        max_iter=p.max_iter, max_cpu_time_s=p.max_cpu_time_s, occupancy_eff_length_m=p.vehicle_length_m,
                        alinea_gain_vph_per_pct=p.alinea_gain_vph_per_pct, alinea_override_frac=p.override_frac)
        self.mpc = RampMeteringMPC(self.net, cfg)
        self.forecast = DemandForecast(sc, n)
        self.u_prev = self.net.default_u()
        self.targets: dict[int, float] = {}
        self.defaults = {k: float(s) for k, s in enumerate(self.net.split_default)}
        self.station_map = load_station_map(p.station_map) if p.station_map else None

    @property
    def solve_times_s(self) -> list[float]:
        return self.mpc.solve_times_s if hasattr(self, "mpc") else []

    @property
    def n_fallbacks(self) -> int:
        return self.mpc.n_fallbacks if hasattr(self, "mpc") else 0

    @property
    def n_suboptimal(self) -> int:
        return self.mpc.n_suboptimal if hasattr(self, "mpc") else 0

    @property
    def n_cpu_capped(self) -> int:
        return self.mpc.n_cpu_capped if hasattr(self, "mpc") else 0

    @property
    def iter_counts(self) -> list[int]:
        return self.mpc.iter_counts if hasattr(self, "mpc") else []

    def decide(self, obs: RampObservation) -> dict[str, float]:
        net, mpc = self.net, self.mpc
        x0 = estimate_state(net, obs.ramps, self.n, self.m_seg, self.p.vehicle_length_m, self.lanes)
        times = obs.t + np.arange(mpc.n) * self.p.model_step_s
        keys = [f"{SUMO_DIR_OF_MODEL[int(j) % 2]}{int(j) // 2}" for j in net.metered_idx]
        occ = np.array([obs.ramps[k].occupancy_down_pct for k in keys])
        if self.fusion is not None:
            x0, occ = self.fused_state(x0, keys, obs.t)
        if self._ctx is not None:  # the state the MPC decides on (compare with segment_watch's rho_true_*)
            for i in range(net.n_seg):
                self._ctx.signals.record(f"mpc_rho_{i}", obs.t, float(x0[i]))
                self._ctx.signals.record(f"mpc_v_{i}", obs.t, float(x0[net.n_seg + i]))
        capped = mpc.n_cpu_capped
        res = mpc.solve(x0, self.forecast(times), self.u_prev, occupancy_pct=occ)
        if mpc.n_cpu_capped > capped:
            self.events.emit(obs.t, self.name, "mpc_cpu_cap",
                             f"IPOPT's CPU-time safety net ({self.p.max_cpu_time_s:g} s) ended the solve: "
                             "this step depends on the machine's load", status=res.status, solve_s=res.solve_s)
        if res.fallback:
            self.events.emit(obs.t, self.name, "fallback", f"MPC failed ({res.status}); ALINEA rates this step",
                             status=res.status, solve_s=res.solve_s)
        self.u_prev = res.u
        if self.p.guidance:
            self.targets = {k: float(s) for k, s in enumerate(res.split)}
            if self._ctx is not None:
                for k, s in self.targets.items():
                    self._ctx.signals.record(f"split_ccw_{k}", obs.t, s)
        cap = self.p.open_rate_vph
        return {key: (math.inf if r >= 0.97 * cap else float(r)) for key, r in zip(keys, res.rates_vph)}

    def fused_state(self, x0: np.ndarray, keys: list[str], t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The state with the estimator's densities and speeds (queues stay the ramp detectors'), and
        the occupancy [%] downstream of each metered merge from the fused density (ALINEA fallback)."""
        from corridor.traffic.macro.metanet import equilibrium_speed

        self.fusion.refresh(t_s)
        net, ns = self.net, self.net.n_seg
        rho = self.fusion.densities()
        if self.station_map is not None:  # segment-mean -> the station scale of the model's calibration
            rho = self.station_map.to_station(rho)
        rho = np.maximum(rho, RHO_FLOOR)
        v = self.fusion.speeds_kmh()
        v = np.where(np.isfinite(v), v, equilibrium_speed(rho, net.v_free_kmh, net.rho_crit, net.a))
        x = x0.copy()
        x[:ns], x[ns:2 * ns] = rho, v
        first = {f"{d}{k}": (dirn * self.n + k) * self.m_seg for dirn, d in enumerate(SUMO_DIR_OF_MODEL)
                 for k in range(self.n)}
        occ = np.array([rho[first[k]] * self.p.vehicle_length_m / 10.0 for k in keys])
        return x, occ

    def guide(self, obs: RampObservation) -> list[Any]:
        if not self.targets:
            return []
        fresh = [vr for vids in obs.new_on_origin.values() for vr in vids]
        moves = guidance_assignments(fresh, self.targets, self.defaults, self.rng, self.choices)
        return [Reroute(moves)] if moves else []
