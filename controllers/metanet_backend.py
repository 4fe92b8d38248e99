"""Pure-METANET backend and its ramp controllers, so macroscopic benchmarks run as scenarios.

``metanet`` (backend) integrates a METANET network (``metanet_networks``; today the Hegyi benchmark
freeway) one model step per tick: ``x_{k+1} = f(x_k, u, d(t_k))`` with the input ``u`` last set by a
``SetMetanetInput`` command, and sums the total time spent exactly as ``ramp_mpc.closed_loop`` does
(``T sum_k TTS(x_{k+1})``), so a scenario run and ``python -m corridor.controllers.hegyi`` agree.

Controllers (period = control step, 60 s): ``metanet_none`` (meter open), ``metanet_alinea`` (ALINEA on
the model density, as ``ramp_mpc.alinea_policy``) and ``metanet_mpc`` (``RampMeteringMPC`` with a
perfect demand forecast, as in Hegyi et al. 2005).  Each may carry the published TTS of its case;
it then reports it beside the run's TTS with the relative difference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.metanet import MetanetNetwork, MetanetParams, total_time_spent_step
from corridor.controllers.metanet_networks import hegyi_demands, hegyi_freeway, hegyi_initial_state
from corridor.controllers.ramp_mpc import MPCConfig, RampMeteringMPC, alinea_policy
from corridor.engine import Backend, Controller, RunContext


@dataclass(frozen=True)
class SetMetanetInput:
    """Hold input ``u`` (meter rates as capacity fractions, then route splits) from now on."""

    u: np.ndarray


NETWORKS = {"hegyi2005": (hegyi_freeway, hegyi_demands, hegyi_initial_state)}


class MetanetBackend(Backend):
    """One METANET network stepped at its model step; TTS and queues as metrics."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        network: Literal["hegyi2005"] = "hegyi2005"
        step_s: float = Field(10.0, gt=0)  # [s] model step = this backend's period

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.period = self.p.step_s
        make_net, self.demands, make_x0 = NETWORKS[self.p.network]
        self.net: MetanetNetwork = make_net(MetanetParams(step_h=self.p.step_s / 3600.0))
        self.x = np.asarray(make_x0(), dtype=float)
        self.u = self.net.default_u()
        self.tts_vh = 0.0
        self.max_queue_veh = np.zeros(self.net.n_orig)

    def demand_at(self, t_s: np.ndarray) -> np.ndarray:
        """Disturbances (len(t), nd) at the given times [s] (the scenario's perfect forecast)."""
        return self.demands(np.asarray(t_s, dtype=float) / 3600.0)

    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        for c in commands:
            if isinstance(c, SetMetanetInput):
                self.u = np.asarray(c.u, dtype=float)

    def tick(self, ctx: RunContext) -> None:
        """Advance one model step from t = ctx.t (the engine advances its clock afterwards)."""
        d = self.demand_at(np.array([ctx.t]))[0]
        self.x = self.net.function(self.x, self.u, d)[0].full().ravel()
        self.tts_vh += float(total_time_spent_step(self.x, self.net))
        _, v, w = self.net.split_x(self.x)
        self.max_queue_veh = np.maximum(self.max_queue_veh, w)
        t_next = ctx.t + self.period
        for j, label in enumerate(self.net.orig_labels):
            ctx.signals.record(f"queue_{label}", t_next, float(w[j]))
        ctx.signals.record("speed_min_kmh", t_next, float(np.min(v)))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        out: dict[str, Any] = {"tts_vh": self.tts_vh}
        for j, label in enumerate(self.net.orig_labels):
            out[f"queue_max_{label}"] = float(self.max_queue_veh[j])
        metered = self.net.metered_idx
        store = self.net.orig_storage_veh[metered]
        out["queue_max_over_storage"] = float(np.max(self.max_queue_veh[metered] / store)) if len(metered) else 0.0
        return out


def find_metanet(ctx: RunContext) -> MetanetBackend:
    for c in ctx.components.values():
        if isinstance(c, MetanetBackend):
            return c
    raise ValueError("metanet controllers need a `metanet` backend in the scenario (backends: ...)")


class MetanetControlParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    control_step_s: float = Field(60.0, gt=0)  # [s]
    published_tts_vh: float | None = Field(None, gt=0)  # the paper's figure for this case [veh h]
    horizon_ctrl_steps: int = Field(7, ge=1, le=60)  # MPC prediction horizon [control steps]
    weight_rate_change: float = Field(0.4, ge=0)
    max_cpu_time_s: float = Field(10.0, gt=0, le=600)  # IPOPT limit per solve [s]


class MetanetNone(Controller):
    """No control: the meters stay at their default (open) input."""

    Params = MetanetControlParams

    def __init__(self, name: str, params: MetanetControlParams | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.period = self.p.control_step_s

    def setup(self, ctx: RunContext) -> None:
        self.backend = find_metanet(ctx)
        super().setup(ctx)

    def observe(self, ctx: RunContext) -> tuple[float, np.ndarray]:
        return ctx.t, self.backend.x.copy()

    def step(self, obs: tuple[float, np.ndarray]) -> list[Any]:
        return []

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        pub = self.p.published_tts_vh
        if pub is None:
            return {}
        tts = self.backend.tts_vh
        return {"tts_published_vh": pub, "tts_rel_diff_published": (tts - pub) / pub}

    def _cfg(self) -> MPCConfig:
        return MPCConfig(horizon_ctrl_steps=self.p.horizon_ctrl_steps, control_step_s=self.p.control_step_s,
                         weight_rate_change=self.p.weight_rate_change, max_cpu_time_s=self.p.max_cpu_time_s)


class MetanetAlinea(MetanetNone):
    """ALINEA on every meter of the model (model density as occupancy, model queue)."""

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        self.policy = alinea_policy(self.backend.net, self._cfg())

    def step(self, obs: tuple[float, np.ndarray]) -> list[Any]:
        t, x = obs
        d = self.backend.demand_at(np.array([t]))
        return [SetMetanetInput(self.policy(0, x, d, self.backend.u))]


class MetanetMpc(MetanetNone):
    """Ramp-metering MPC on the model itself with a perfect forecast (Hegyi et al. 2005)."""

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        self.mpc = RampMeteringMPC(self.backend.net, self._cfg())
        self.u_prev = self.backend.net.default_u()

    @property
    def solve_times_s(self) -> list[float]:
        return self.mpc.solve_times_s if hasattr(self, "mpc") else []

    def step(self, obs: tuple[float, np.ndarray]) -> list[Any]:
        t, x = obs
        times = t + np.arange(self.mpc.n) * self.backend.period
        res = self.mpc.solve(x, self.backend.demand_at(times), self.u_prev)
        if res.fallback:
            self.events.emit(t, self.name, "fallback", f"MPC failed ({res.status}); ALINEA this step",
                             status=res.status)
        self.u_prev = res.u
        return [SetMetanetInput(res.u)]

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        out = super().finish(ctx)
        t = np.asarray(self.mpc.solve_times_s) if self.mpc.solve_times_s else np.array([math.nan])
        out.update(mpc_solve_p50_s=float(np.percentile(t, 50)), mpc_solve_p95_s=float(np.percentile(t, 95)),
                   mpc_solves=len(self.mpc.solve_times_s), mpc_fallbacks=self.mpc.n_fallbacks)
        return out
