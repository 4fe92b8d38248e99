"""A city-scale traffic link: every aircraft's position report over a lossy, delayed broadcast channel,
vectorised over the fleet (registered as ``city_link``).

The MAVLink link (``mavlink_link``) carries real MAVLink 2 bytes and keeps a Kalman track per
receiver and source; MAVLink's one-byte system id caps it at 254 aircraft, and its receiver x source
tables grow as N^2, so a city of thousands needs this one. It models what a Remote-ID / ADS-B style
broadcast does to an avoidance controller's picture, with the scenario's ``channels.<name>``
(``ChannelConfig``): each aircraft broadcasts (t, position, velocity) every ``1 / position_hz``; a
broadcast is lost with the channel's loss probability (Bernoulli, or a Gilbert-Elliott chain per
source), otherwise it arrives after ``latency_s + U(0, jitter_s)``; receivers farther than
``range_m`` do not hear it (checked per pair by the consumer, :meth:`CityLink.picture`). Every
receiver keeps the newest report per source and extrapolates it at constant velocity to the query
time; its uncertainty radius is ``sigma_factor * sqrt(meas_noise^2 + (vel_noise * age)^2)``. Reports
older than ``stale_after_s`` are dropped. What differs from the MAVLink link: no bytes, one loss
draw per broadcast (all receivers miss a lost one: the per-pair loss rate is the same, its
correlation across receivers is not), no Kalman filter (a constant-velocity extrapolation).
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.channel import ChannelConfig, GilbertElliottLoss
from corridor.engine import Component, Metric, Need, Phase, RunContext


class Picture(NamedTuple):
    """The newest report of every source, extrapolated to the query time (struct of arrays)."""

    valid: np.ndarray  # (N,) bool: a report younger than stale_after_s
    pos: np.ndarray  # (N, 3) [m]
    vel: np.ndarray  # (N, 3) [m/s]
    sigma_m: np.ndarray  # (N,) [m]
    range_m: float  # [m] receivers farther than this did not hear the source


class CityLink(Component):
    """Vectorised broadcast of position reports (see the module docstring)."""

    phase = Phase.COMMUNICATE
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('link_delivery_ratio', '1', 'Share of the broadcast reports that were delivered.'),
        Metric('link_aoi_mean_s', 's', 'Mean age of the newest report per source at the link ticks.'),
        Metric('link_sent', '1', 'Reports broadcast.'),
    )
    needs: ClassVar[dict[str, Need]] = {"backend": Need(role="air", name_at="params.backend")}
    provides: ClassVar[frozenset[str]] = frozenset({"city_link"})
    period_source: ClassVar[str | None] = "params.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        backend: str = "air"
        channel: str | None = None  # name in the scenario's ``channels``; None = ChannelConfig()
        position_hz: float = Field(2.0, gt=0.0)  # [Hz] report rate per aircraft
        meas_noise_m: float = Field(0.5, gt=0.0)  # [m]
        vel_noise_mps: float = Field(0.3, gt=0.0)  # [m/s]
        sigma_factor: float = Field(3.0, ge=0.0)
        stale_after_s: float = Field(3.0, gt=0.0)  # [s]

        @property
        def period_s(self) -> float:
            return 1.0 / self.position_hz

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        if params.channel is not None and params.channel not in scenario.channels:
            known = ", ".join(scenario.channels) or "none"
            raise ValueError(f"{name}.params.channel: no channel {params.channel!r} in the scenario (known: {known})")
        self.cfg: ChannelConfig = scenario.channels[params.channel] if params.channel else ChannelConfig()
        self.sent = self.delivered = 0
        self.aoi_sum_s, self.aoi_n = 0.0, 0

    def setup(self, ctx: RunContext) -> None:
        self.rng = ctx.rng(f"{self.name}/channel")
        self.n = len(self.backend.aircraft)
        self.t_meas = np.full(self.n, -np.inf)  # [s] newest delivered report per source
        self.p = np.zeros((self.n, 3))
        self.v = np.zeros((self.n, 3))
        self.bad = np.zeros(self.n, dtype=bool)  # Gilbert-Elliott state per source
        self.queue: list[tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]] = []

    def _lost(self) -> np.ndarray:
        loss = self.cfg.loss
        if isinstance(loss, GilbertElliottLoss):
            u = self.rng.random(self.n)
            self.bad = np.where(self.bad, u >= loss.p_bad_to_good, u < loss.p_good_to_bad)
            return self.rng.random(self.n) < np.where(self.bad, loss.loss_bad, loss.loss_good)
        return self.rng.random(self.n) < loss.p

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        if len(s) and len(s) != self.n:
            raise ValueError(f"{self.name}: the snapshot has {len(s)} rows, the air backend {self.n}: city_link "
                             "runs with the air backend as the only backend")
        if len(s):
            rows = np.flatnonzero(~self._lost())
            delay = self.cfg.latency_s + self.cfg.jitter_s * self.rng.random(len(rows))
            self.queue.append((ctx.t + delay, rows, ctx.t, s.position[rows].copy(), s.velocity[rows].copy()))
            self.sent += self.n
            self.delivered += len(rows)
        self._deliver(ctx.t)
        known = np.isfinite(self.t_meas)
        if known.any():
            self.aoi_sum_s += float(np.sum(ctx.t - self.t_meas[known]))
            self.aoi_n += int(known.sum())

    def _deliver(self, t_s: float) -> None:
        keep = []
        for t_due, rows, t_meas, p, v in self.queue:
            due = t_due <= t_s + 1e-9
            r = rows[due]
            newer = t_meas > self.t_meas[r]
            r = r[newer]
            self.t_meas[r], self.p[r], self.v[r] = t_meas, p[due][newer], v[due][newer]
            if not due.all():
                keep.append((t_due[~due], rows[~due], t_meas, p[~due], v[~due]))
        self.queue = keep

    def picture(self, t_s: float) -> Picture:
        """Every source's newest report at ``t_s`` (extrapolated); invalid when stale or never heard."""
        pr = self.params
        self._deliver(t_s)
        age = t_s - self.t_meas
        valid = age <= pr.stale_after_s
        age = np.where(valid, age, 0.0)
        pos = self.p + self.v * age[:, None]
        sigma = pr.sigma_factor * np.sqrt(pr.meas_noise_m**2 + (pr.vel_noise_mps * age) ** 2)
        return Picture(valid, pos, self.v.copy(), sigma, self.cfg.range_m)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"link_delivery_ratio": self.delivered / max(self.sent, 1),
                "link_aoi_mean_s": self.aoi_sum_s / self.aoi_n if self.aoi_n else float("nan"),
                "link_sent": float(self.sent)}
