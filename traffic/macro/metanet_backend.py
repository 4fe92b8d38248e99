"""Pure-METANET backend, so macroscopic benchmarks run as scenarios.

``metanet`` (backend) integrates a METANET network (``metanet_networks``; today the Hegyi benchmark
freeway) one model step per tick: ``x_{k+1} = f(x_k, u, d(t_k))`` with the input ``u`` last set by a
``SetMetanetInput`` command, and sums the total time spent exactly as ``ramp_mpc.closed_loop`` does
(``T sum_k TTS(x_{k+1})``), so a scenario run and ``python -m corridor.controllers.ramp_metering.hegyi``
agree.  Its controllers live in ``corridor.controllers.ramp_metering.metanet_components``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Backend, Metric, Need, RunContext
from corridor.traffic.macro.metanet import MetanetNetwork, MetanetParams, total_time_spent_step
from corridor.traffic.macro.metanet_networks import hegyi_demands, hegyi_freeway, hegyi_initial_state


@dataclass(frozen=True)
class SetMetanetInput:
    """Hold input ``u`` (meter rates as capacity fractions, then route splits) from now on."""

    u: np.ndarray


# how METANET controllers name their backend peer (exactly one in the run)
NEEDS_METANET = Need(role="metanet", hint="add a `metanet` backend to the scenario (backends: ...)")

NETWORKS = {"hegyi2005": (hegyi_freeway, hegyi_demands, hegyi_initial_state)}


class MetanetBackend(Backend):
    """One METANET network stepped at its model step; TTS and queues as metrics."""

    provides: ClassVar[frozenset[str]] = frozenset({"metanet"})
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('tts_vh', 'veh*h',
               'Total time spent in the macroscopic model (mainline and origin queues).'),
        Metric('queue_max_*', 'veh',
               'Longest queue at origin <name>.'),
        Metric('queue_max_over_storage', '1',
               'Largest metered queue relative to its storage.'),
    )
    period_source: ClassVar[str | None] = "p.step_s"  # [s] the model step

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        network: Literal["hegyi2005"] = "hegyi2005"
        step_s: float = Field(10.0, gt=0)  # [s] model step = this backend's period

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
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



