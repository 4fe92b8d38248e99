"""A fixed-rate ramp meter on corridor's METANET backend: every meter at ``rate`` (fraction of the
ramp capacity) from ``start_s`` on; reports ``example_meter.rate`` and ``example_meter.commands``."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Controller, Need, RunContext
from corridor.traffic.macro.metanet_backend import NEEDS_METANET, MetanetBackend, SetMetanetInput


class FixedMeter(Controller):
    needs: ClassVar[dict[str, Need]] = {"backend": NEEDS_METANET}  # set by the engine before setup
    period_source: ClassVar[str | None] = "p.control_step_s"
    backend: MetanetBackend

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        rate: float = Field(0.5, ge=0, le=1)  # fraction of the ramp capacity
        start_s: float = Field(0.0, ge=0)  # [s]
        control_step_s: float = Field(60.0, gt=0)  # [s]

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.commands = 0

    def observe(self, ctx: RunContext) -> float:
        return ctx.t

    def step(self, t: float) -> list[Any]:
        if t < self.p.start_s:
            return []
        u = np.asarray(self.backend.net.default_u(), dtype=float).copy()
        u[: self.backend.net.n_metered] = self.p.rate
        self.commands += 1
        return [SetMetanetInput(u)]

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"example_meter.rate": self.p.rate, "example_meter.commands": self.commands}
