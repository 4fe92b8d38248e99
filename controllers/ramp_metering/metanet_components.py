"""Ramp controllers on the pure-METANET backend (``corridor.traffic.macro.metanet_backend``).

Controllers (period = control step, 60 s): ``metanet_none`` (meter open), ``metanet_alinea`` (ALINEA on
the model density, as ``ramp_mpc.alinea_policy``) and ``metanet_mpc`` (``RampMeteringMPC`` with a
perfect demand forecast, as in Hegyi et al. 2005).  Each may carry the published TTS of its case;
it then reports it beside the run's TTS with the relative difference.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC, alinea_policy
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.traffic.macro.metanet_backend import NEEDS_METANET, MetanetBackend, SetMetanetInput


class MetanetControlParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    control_step_s: float = Field(60.0, gt=0)  # [s]
    published_tts_vh: float | None = Field(None, gt=0)  # the paper's figure for this case [veh h]
    horizon_ctrl_steps: int = Field(7, ge=1, le=60)  # MPC prediction horizon [control steps]
    weight_rate_change: float = Field(0.4, ge=0)
    max_cpu_time_s: float = Field(10.0, gt=0, le=600)  # IPOPT limit per solve [s]


MPC_METRICS = (
    Metric("mpc_solve_p50_s", "s", "Median MPC solve time (wall clock)."),
    Metric("mpc_solve_p95_s", "s", "95th percentile MPC solve time (wall clock)."),
    Metric("mpc_solves", "1", "MPC solves."),
    Metric("mpc_fallbacks", "1", "MPC steps that fell back (no usable solution)."),
)


class MetanetNone(Controller):
    """No control: the meters stay at their default (open) input."""

    Params = MetanetControlParams
    needs: ClassVar[dict[str, Need]] = {"backend": NEEDS_METANET}
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('tts_published_vh', 'veh*h',
               'The published total time spent of the benchmark this run reproduces.'),
        Metric('tts_rel_diff_published', '1',
               "Relative difference of this run's total time spent to the published one."),
    )
    period_source: ClassVar[str | None] = "p.control_step_s"
    backend: MetanetBackend

    def __init__(self, name: str, params: MetanetControlParams | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()

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

    metrics: ClassVar[tuple[Metric, ...] | None] = MetanetNone.metrics + MPC_METRICS

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
