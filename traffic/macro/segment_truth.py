"""Perfect information for the ramp MPC (``controller.segment_truth``): a ``segment_estimate`` provider
that hands the MPC SUMO's ground truth per METANET segment (density, space-mean speed) instead of an
estimate.  A diagnostic baseline, not a sensor: with it, ``air_ground_watch`` shows how much of the
loop-failure loss any estimator (loops, cameras, fusion) could recover at best, and whether the MPC's
TTS responds to the density picture at all.

It reads the snapshot (ground truth, as ``segment_watch`` does), DECIDE phase, every ``period_s``,
and again whenever the MPC calls :meth:`refresh` (so the MPC decides on the state of that instant).  Segments without vehicles report the
speed as nan (the MPC then takes the equilibrium speed of the density).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Phase, RunContext
from corridor.traffic.networks.segments import RingIndex, RingSegments
from corridor.traffic.sumo.road_spec import road_spec


class SegmentTruth(Component):
    """Ground-truth segment density [veh/km/lane] and speed [km/h] (provides ``segment_estimate``)."""

    phase = Phase.DECIDE
    provides: ClassVar[frozenset[str]] = frozenset({"segment_estimate"})
    period_source: ClassVar[str | None] = "params.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        period_s: float = Field(5.0, gt=0.0)  # [s]
        segments_per_link: int = Field(1, ge=1, le=8)  # the MPC's m

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.kf = None  # no filter (segment_watch reports no fused RMSE for it)
        self.uav_received = 0

    def setup(self, ctx: RunContext) -> None:
        lm = ctx.snapshot.road.tables.landmarks
        seg = RingSegments.build(lm, road_spec(ctx.scenario).network.params, self.params.segments_per_link)
        self.index = RingIndex(seg)
        self._rho = np.zeros(seg.n_seg)
        self._v = np.full(seg.n_seg, np.nan)
        self._ctx = ctx

    def tick(self, ctx: RunContext) -> None:
        self.refresh(ctx.t)

    def refresh(self, t_s: float) -> None:
        """The truth of the current snapshot (the interface of ``segment_fusion``)."""
        if self._ctx.snapshot.road is not None:
            self._rho, self._v = self.index.truth(self._ctx.snapshot)

    def densities(self) -> np.ndarray:
        return self._rho.copy()

    def speeds_kmh(self) -> np.ndarray:
        return self._v.copy()
