"""Samples of every road vehicle for the report's time-space diagram (``corridor.analysis.report_series``).

At every ``period_s`` the monitor keeps, for each vehicle on the road, the time [s], its position
along the road (its east coordinate [m]: corridor's road networks are laid along x, the ramp joining
from the side), its speed [m/s] and its role.  At the end it writes them to the batch folder as
``timespace/ts-<run_id>.npz`` (arrays ``t``, ``x``, ``speed``, ``role``; float32), not as run signals:
a few hundred thousand samples would swamp the signal plots and the Rerun timeline.  It writes no
metric column and changes nothing in the run."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.sumo.trips import NEEDS_ROAD, road_frame

FILE = "timespace/ts.npz"  # per run: timespace/ts-<run_id>.npz


class TimeSpace(Component):
    phase = Phase.DETECT
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "p.period_s"
    metrics: ClassVar[tuple[Metric, ...] | None] = ()  # writes a file, no column

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        period_s: float = Field(1.0, gt=0.0, le=60.0)  # [s] sampling period (a multiple of dt)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self._parts: list[tuple[np.ndarray, ...]] = []

    def setup(self, ctx: RunContext) -> None:
        road_frame(ctx)  # fails early without a road

    def tick(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        if not len(r):
            return
        s = ctx.snapshot
        pos, vel = s.position[r.sl], s.velocity[r.sl]
        self._parts.append((np.full(len(r), ctx.t, np.float32), pos[:, 0].astype(np.float32),
                            np.hypot(vel[:, 0], vel[:, 1]).astype(np.float32), s.role[r.sl].astype(np.int8)))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        cols = [np.concatenate(c) if c else np.zeros(0, np.float32) for c in zip(*self._parts, strict=True)] \
            if self._parts else [np.zeros(0, np.float32)] * 3 + [np.zeros(0, np.int8)]
        np.savez_compressed(ctx.output_path(FILE), **dict(zip(("t", "x", "speed", "role"), cols, strict=True)))
        return {}
