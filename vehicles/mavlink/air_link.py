"""The engine's MAVLink link: every aircraft's telemetry as MAVLink 2 bytes over a scenario channel,
and, per receiving UAV, a Kalman-tracked picture of the other aircraft.

Each COMMUNICATE tick (period 1 / position rate, default 0.1 s) the link

1. takes the air entities of the world snapshot (UAVs and piloted aircraft of the air backend),
2. publishes what is due (HEARTBEAT 1 Hz, GLOBAL_POSITION_INT + LOCAL_POSITION_NED for UAVs,
   ADSB_VEHICLE for piloted aircraft) through :class:`~corridor.vehicles.mavlink.link.MavlinkLink`
   over a :class:`~corridor.channel.Channel` configured from the scenario's ``channels.<name>``,
3. decodes what the channel delivered (CRC-checked; corrupted bytes are counted and dropped) and
   keeps, per receiver and source, the newest report.

Avoidance controllers call :meth:`AirLink.picture` at their own period: the buffered reports of that
receiver are fused into its row of a :class:`~corridor.vehicles.tracks.stack.TrackStack` (one
constant-velocity Kalman filter per receiver and source, all updated in one stacked pass; tested
against filterpy's ``TrackTable``) and every track is predicted to the query time. The reports wait
in a :class:`~corridor.vehicles.mavlink.link.LatestReports` (arrays over receiver x source, filled
per datagram, not per copy); :meth:`AirLink.pictures` serves every governed UAV in one call. Only the newest report
per source since the previous query is fused: the reports carry position *and* velocity, so an
intermediate sample 0.1 s older adds almost nothing, and lazy fusion keeps the cost proportional to
the controllers' rate (the ``none`` variant tracks nothing). Each receiver tracks only its
``max_tracks`` nearest reporting UAVs (default 8, the control tube's intruder limit) plus every
piloted aircraft: a swarm's far side cannot matter within an avoidance horizon, and the Kalman
updates are the link's main cost. A controller may also pass a :class:`Relevance` range (as real
ADS-B / Remote-ID consumers filter by range): a UAV whose report lies farther than
``base_m + per_speed_s * |v_report|`` from the receiver cannot reach it within the controller's
horizon, so its report is not fused and its track is dropped (the message is still received and
counted by the link; the track restarts from the first report inside the range, position and
velocity both measured). Tracks without a report for ``stale_after_s`` are dropped, so a
silent aircraft disappears from the picture (never ground truth).

``udp_mirror: udpout:HOST:PORT`` copies every datagram the link sends to a UDP address (a ground
station such as QGroundControl sees each aircraft as its own MAVLink system); ``realtime_factor``
paces the run so that simulated time never runs ahead of wall time x factor (the link sleeps in its
tick), otherwise the mirror replays the flight as fast as the simulation runs. ``log_path`` writes
the same bytes to a raw MAVLink file under the batch's output folder, one per run.

The avoidance runs on board each UAV, so its commands go straight to the UAV's own autopilot (the
command bus), not through a ground-station uplink. The first link tick (t = 0) precedes the first
world snapshot and publishes nothing.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, ClassVar, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from corridor.channel import Channel, ChannelConfig
from corridor.engine import Component, Metric, Need, Phase, RunContext, relative_output_path
from corridor.snapshot import Kind
from corridor.vehicles.mavlink.link import LatestReports, LinkRates, MavlinkLink
from corridor.vehicles.tracks.agent import TrackedAgent
from corridor.vehicles.tracks.stack import TrackStack


class Relevance(NamedTuple):
    """Range beyond which a reporting UAV cannot matter to a receiver within its avoidance horizon:
    ``range_m = base_m + per_speed_s * |v|`` [m] for a report with speed |v| [m/s]. A controller
    derives it from its own speed bound, horizon, separation radius and a margin (track sigma,
    report age, the time to its next decision)."""

    base_m: float  # [m]
    per_speed_s: float  # [s] (the horizon over which the other's speed counts)


class AirLink(Component):
    """MAVLink link + per-UAV track tables (registered in BACKENDS as ``mavlink_link``)."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('link_delivery_ratio', '1',
               'Share of the position reports sent over the link that were delivered.'),
        Metric('link_aoi_mean_s', 's',
               'Mean age of information of the delivered reports.'),
        Metric('link_aoi_max_s', 's',
               'Largest age of information of a delivered report.'),
        Metric('link_sent', '1',
               'Reports sent.'),
        Metric('link_delivered', '1',
               'Reports delivered.'),
        Metric('link_lost', '1',
               "Reports lost by the channel's loss model."),
        Metric('link_out_of_range', '1',
               'Reports lost out of range.'),
        Metric('link_dropped_after_end', '1',
               'Reports in flight when the run ended.'),
        Metric('link_dropped_overflow', '1',
               'Reports dropped by a full queue.'),
        Metric('link_fused_reports', '1',
               "Reports fused into the ground station's picture."),
        Metric('link_paced_sleep_s', 's',
               'Wall-clock time slept to pace the run (real-time factor set).'),
        Metric('mavlink_*', '1',
               'MAVLink 2 byte-level counts: datagrams, bytes, messages, bad CRC, bad data, dropped bytes, corrupted datagrams.'),
    )
    phase = Phase.COMMUNICATE
    needs: ClassVar[dict[str, Need]] = {"backend": Need(role="air", name_at="params.backend")}
    provides: ClassVar[frozenset[str]] = frozenset({"air_link"})
    period_source: ClassVar[str | None] = "params.period_s"  # [s] 1 / position rate

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        backend: str = "air"  # name of the air backend whose aircraft join the link
        channel: str | None = None  # name in the scenario's ``channels``; None = ChannelConfig()
        heartbeat_hz: float = Field(1.0, gt=0.0)
        position_hz: float = Field(10.0, gt=0.0)
        adsb_hz: float = Field(10.0, gt=0.0)
        bit_error_rate: float = Field(0.0, ge=0.0, le=0.5)  # per received bit
        udp_mirror: str | None = None  # e.g. "udpout:127.0.0.1:14550" for a real ground station
        # pace the run for the mirror: simulated time never runs ahead of wall time x this factor
        # (1.0: real time, 2.0: twice as fast); None: as fast as the simulation goes (~9x real time)
        realtime_factor: float | None = Field(None, gt=0.0, le=1000.0)
        log_path: str | None = None  # write every sent byte to this raw MAVLink file: a path relative
        #   to the batch's output folder (--out); the run id is added to the name (``mavlink/link.tlog``
        #   -> ``<out>/mavlink/link-none-s0.tlog``)
        process_noise: float = Field(2.0, gt=0.0)  # [m^2/s^3] white acceleration density of the CV model
        meas_noise_m: float = Field(0.5, gt=0.0)  # [m] position measurement std
        vel_noise_mps: float = Field(0.3, gt=0.0)  # [m/s] velocity measurement std
        stale_after_s: float = Field(3.0, gt=0.0)  # [s] drop a track without reports for this long
        sigma_factor: float = Field(3.0, ge=0.0)  # uncertainty radius = factor x position std
        max_tracks: int = Field(8, ge=1, le=256)  # [aircraft] per receiver: nearest reporting UAVs tracked (+ every piloted)
        # MAVLink dialect: pymavlink's ``common``, or corridor's ``corridor_traffic`` (common + the
        # TRAFFIC_SEGMENT_ESTIMATE downlink of the UAV cameras; generated by mavgen on first use)
        dialect: Literal["common", "corridor_traffic"] = "common"

        @field_validator("log_path")
        @classmethod
        def _relative_log_path(cls, v: str | None) -> str | None:
            return None if v is None else relative_output_path(v)

        @property
        def period_s(self) -> float:
            """The link's period [s]: one position report per aircraft per tick."""
            return 1.0 / self.position_hz

        @model_validator(mode="after")
        def _pacing_needs_mirror(self) -> AirLink.Params:
            if self.realtime_factor is not None and self.udp_mirror is None:
                raise ValueError("realtime_factor paces the UDP mirror: set udp_mirror too")
            return self

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        if params.channel is not None and params.channel not in scenario.channels:
            known = ", ".join(scenario.channels) or "none"
            raise ValueError(f"{name}.params.channel: no channel {params.channel!r} in the scenario (known: {known})")
        self.cfg = scenario.channels[params.channel] if params.channel else ChannelConfig()
        o = scenario.origin
        self.origin = (o.lat, o.lon, o.alt)
        self.link: MavlinkLink | None = None
        self.piloted: set[str] = set()
        self.log_path: Path | None = None  # resolved under the run's output folder in setup
        self.latest: LatestReports | None = None  # receiver x source: the newest report not yet fused
        self.tracks: TrackStack | None = None  # receiver x source: Kalman tracks
        self._rx: dict[str, int] = {}  # receiver id -> row
        self._piloted_col = np.zeros(0, dtype=bool)  # per source column: piloted aircraft
        self._calls = 0  # picture calls (track creation order)
        self.fused = 0
        self._pace_origin: tuple[float, float] | None = None  # (sim time [s], wall clock [s]) of the first tick
        self.paced_sleep_s = 0.0

    def setup(self, ctx: RunContext) -> None:
        p, backend = self.params, self.backend
        channel = Channel(self.cfg, ctx.rng(f"{self.name}/channel"), t_end_s=ctx.duration)
        self.log_path = ctx.output_path(p.log_path) if p.log_path else None
        self.link = MavlinkLink(
            channel, self.origin, LinkRates(p.heartbeat_hz, p.position_hz, p.adsb_hz),
            udp_mirror=p.udp_mirror, log_path=str(self.log_path) if self.log_path else None,
            bit_error_rate=p.bit_error_rate, rng=ctx.rng(f"{self.name}/bits"), dialect=self.dialect_module(),
        )
        receivers = []
        for a in backend.aircraft:
            if a.is_piloted:
                self.link.add_piloted(a.id)
                self.piloted.add(a.id)
            else:
                self.link.add_uav(a.id)
                receivers.append(a.id)
        sources = [a.id for a in backend.aircraft]
        self.latest = self.link.latest_table(receivers, sources)
        self.tracks = TrackStack(len(receivers), len(sources), 3, p.process_noise, p.meas_noise_m, p.vel_noise_mps)
        self._rx = {id: k for k, id in enumerate(receivers)}
        self._piloted_col = np.array([src in self.piloted for src in sources], dtype=bool)

    def dialect_module(self) -> Any:
        """The generated dialect module (None: pymavlink's common)."""
        if self.params.dialect == "common":
            return None
        from corridor.vehicles.mavlink.dialect import dialect

        return dialect()

    def send_to_gcs(self, t_s: float, src: str, messages: list[Any], src_pos: np.ndarray | None = None) -> int:
        """Aircraft ``src`` -> ground station over the channel (one datagram); bytes sent."""
        return self.link.send_to_gcs(t_s, src, messages, src_pos)

    def take_estimates(self) -> list[tuple[float, str, float, Any]]:
        """TRAFFIC_SEGMENT_ESTIMATE messages the ground station received since the last call:
        (t_recv [s], src, t_sent [s], message)."""
        out, self.link.estimates = self.link.estimates, []
        return out

    def _pace(self, t_s: float) -> None:
        """With ``realtime_factor``: sleep until wall time has caught up with simulated time."""
        factor = self.params.realtime_factor
        if factor is None:
            return
        now = time.perf_counter()
        if self._pace_origin is None:
            self._pace_origin = (t_s, now)
            return
        t0, wall0 = self._pace_origin
        wait = wall0 + (t_s - t0) / factor - now
        if wait > 0.0:
            time.sleep(wait)
            self.paced_sleep_s += wait

    def tick(self, ctx: RunContext) -> None:
        self._pace(ctx.t)
        s = ctx.snapshot
        air = (s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT)
        if air.any():
            ids = s.ids[air]
            pos = s.position[air]
            self.link.channel.set_positions_arrays(ids, pos)
            self.link.publish(ctx.t, ids, pos, s.velocity[air], s.heading[air])
        self.link.receive_latest_table(ctx.t, self.latest)  # the newest report per receiver and source

    def inject(self, t_s: float, src: str, payload: bytes, dst: str | None = None) -> None:
        """Put raw bytes on the channel (tests: garbage must be counted and dropped)."""
        self.link.inject(t_s, src, payload, dst)

    def picture(
        self, uav_id: str, t_s: float, own_pos: np.ndarray | None = None, relevance: Relevance | None = None
    ) -> tuple[TrackedAgent, ...]:
        """The other aircraft as ``uav_id`` knows them at ``t_s``: fused, tracked, predicted.

        With ``own_pos`` [m], only the ``max_tracks`` nearest reporting UAVs (plus every piloted
        aircraft) are fused; tracks of UAVs that drop out of that set are removed. With a
        ``relevance`` range as well, UAV reports outside it are not fused either (same removal).
        """
        own = None if own_pos is None else np.asarray(own_pos, float).reshape(1, 3)
        return self.pictures([uav_id], t_s, own, [relevance])[0]

    def pictures(
        self, uav_ids: list[str], t_s: float, own_pos: np.ndarray | None = None,
        relevance: list[Relevance | None] | None = None,
    ) -> list[tuple[TrackedAgent, ...]]:
        """:meth:`picture` for several receivers at once (``own_pos`` (k, 3), one relevance each):
        the pending reports of all of them are chosen and fused in one stacked Kalman pass."""
        if not uav_ids:
            return []
        rows = np.array([self._rx[u] for u in uav_ids])
        lat, tr = self.latest, self.tracks
        fresh = lat.fresh[rows]
        chosen = self._nearest(rows, fresh, own_pos, relevance)
        tr.kill(_scatter(tr.alive.shape, rows, tr.alive[rows] & fresh & ~chosen))
        r_k, cols = np.nonzero(chosen)
        r = rows[r_k]
        z = np.concatenate([lat.p_enu[r, cols], lat.v_enu[r, cols]], axis=1)
        order = self._calls * 2**32 + lat.first[r, cols]
        self.fused += int(tr.fuse(r, cols, lat.t_meas_s[r, cols], z, order).sum())
        self._calls += 1
        lat.fresh[rows] = False
        tr.drop_stale(rows, t_s, self.params.stale_after_s)
        return self._predicted(rows, t_s)

    def _predicted(self, rows: np.ndarray, t_s: float) -> list[tuple[TrackedAgent, ...]]:
        """Every live track of each receiver row at ``t_s`` as TrackedAgents, in creation order."""
        tr = self.tracks
        r_k, cols = np.nonzero(tr.alive[rows])
        r = rows[r_k]
        x, cov = tr.predict(r, cols, t_s)
        # uncertainty radius: factor x the largest position standard deviation of each track
        var = np.maximum(np.maximum(cov[:, 0, 0], cov[:, 1, 1]), cov[:, 2, 2])
        sigma = (self.params.sigma_factor * np.sqrt(var)).tolist()
        out: list[list[tuple[int, TrackedAgent]]] = [[] for _ in range(rows.size)]
        srcs, piloted, order = self.latest.sources, self._piloted_col, tr.order[r, cols].tolist()
        for i, (k, c) in enumerate(zip(r_k.tolist(), cols.tolist(), strict=True)):
            out[k].append((order[i], TrackedAgent(srcs[c], x[i, :3].copy(), x[i, 3:6].copy(), sigma[i],
                                                  bool(piloted[c]))))
        return [tuple(a for _, a in sorted(row, key=lambda o: o[0])) for row in out]

    def _nearest(
        self, rows: np.ndarray, fresh: np.ndarray, own_pos: np.ndarray | None,
        relevance: list[Relevance | None] | None,
    ) -> np.ndarray:
        """Which pending reports (k, n_src) each receiver fuses: every piloted report plus the
        ``max_tracks`` UAV reports nearest to its ``own_pos`` (and, with a relevance range, inside
        it); all of them without ``own_pos``, or when a receiver without a range has at most
        ``max_tracks`` pending."""
        n = self.params.max_tracks
        if own_pos is None:
            return fresh
        rel = relevance or [None] * rows.size
        has_rel = np.array([r is not None for r in rel])
        pending = fresh.sum(axis=1)
        apply = ~((pending <= n) & ~has_rel) & (pending > 0)
        if not apply.any():
            return fresh
        lat = self.latest
        d = lat.p_enu[rows] - np.asarray(own_pos, float)[:, None, :]
        dist = np.sqrt(np.einsum("ksd,ksd->ks", d, d))
        cand = fresh & ~self._piloted_col & apply[:, None]
        if has_rel.any():
            base = np.array([r.base_m if r is not None else np.inf for r in rel])
            per_speed = np.array([r.per_speed_s if r is not None else 0.0 for r in rel])
            v = lat.v_enu[rows]
            reach = base[:, None] + per_speed[:, None] * np.sqrt(np.einsum("ksd,ksd->ks", v, v))
            cand &= dist < reach
        key = np.where(cand, dist, np.inf)
        if key.shape[1] > n:
            near = np.argpartition(key, n - 1, axis=1)[:, :n]
            sel = np.zeros_like(cand)
            np.put_along_axis(sel, near, True, axis=1)
            cand &= sel
        return np.where(apply[:, None], cand | (fresh & self._piloted_col), fresh)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._pace(ctx.t)  # the last ticks after this link's last tick are paced too
        st = self.link.channel.stats()
        out = {
            "link_delivery_ratio": st.delivery_ratio,
            "link_aoi_mean_s": st.aoi_mean_s,
            "link_aoi_max_s": st.aoi_max_s,
            "link_sent": float(st.sent),
            "link_delivered": float(st.delivered),
            "link_lost": float(st.lost_random),
            "link_out_of_range": float(st.out_of_range),
            "link_dropped_after_end": float(st.dropped_after_end),
            "link_dropped_overflow": float(st.dropped_overflow),
            "link_fused_reports": float(self.fused),
        }
        if self.params.realtime_factor is not None:
            out["link_paced_sleep_s"] = self.paced_sleep_s
        out.update(self.link.stats("mavlink_"))
        return out

    def close(self) -> None:
        if self.link is not None:
            self.link.close()


def _scatter(shape: tuple[int, ...], rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A False array of ``shape`` with ``values`` at ``rows``."""
    out = np.zeros(shape, dtype=bool)
    out[rows] = values
    return out
