"""The traffic centre's segment estimator as an engine component (``controller.segment_fusion``): loop
stations (the ``ramp_detectors`` peer, faults included) and the UAV cameras' TRAFFIC_SEGMENT_ESTIMATE
messages (received by the ground station of the MAVLink link) fused per METANET segment
(:class:`corridor.traffic.macro.fusion.SegmentFilter`).  The ``ramp_mpc`` controller takes its state from
here when its ``estimator`` names this component.

DECIDE phase; :meth:`refresh` is idempotent (new loop intervals and newly received messages only), so
the MPC calls it too and always decides on everything the centre has at that instant.  Without a link
(``link: null``) it is a loop-only filter.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.macro.fusion import FusionParams, SegmentFilter
from corridor.traffic.macro.loop_state import load_station_map, loop_speed_kmh
from corridor.traffic.sensing.detectors import DIRECTIONS, NEEDS_DETECTORS, RampDetectors, RampMeasurement


class SegmentFusion(Component):
    """Per-segment Kalman filter of loops + UAV camera estimates (provides ``segment_estimate``)."""

    phase = Phase.DECIDE
    needs: ClassVar[dict[str, Need]] = {"det": NEEDS_DETECTORS,
                                        "link": Need(role="air_link", name_at="params.link", optional=True)}
    provides: ClassVar[frozenset[str]] = frozenset({"segment_estimate"})
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('fusion_uav_estimates', '1',
               'UAV segment estimates received.'),
        Metric('fusion_uav_aoi_mean_s', 's',
               'Mean age of the UAV estimates on arrival.'),
        Metric('fusion_uav_aoi_max_s', 's',
               'Largest age of a UAV estimate on arrival.'),
        Metric('fusion_stations_downweighted', '1',
               'Detector stations whose weight fell below 0.5 (judged faulty).'),
        Metric('fusion_stations_zero', '1',
               'Detector stations that reported zeros.'),
        Metric('fusion_zero_rejected', '1',
               'Zero reports rejected.'),
    )
    period_source: ClassVar[str | None] = "params.period_s"
    det: RampDetectors

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        link: str | None = "link"  # MAVLink link whose ground station receives the camera estimates
        period_s: float = Field(5.0, gt=0.0)  # [s]
        segments_per_link: int = Field(1, ge=1, le=8)  # the MPC's m
        vehicle_length_m: float = Field(5.0, gt=0.0)  # occupancy [%] -> density: occ 10 / length
        # Zero test (a traffic centre's routine loop-data check): an interval in which a station counted
        # no vehicle at 0 % occupancy while the median station of its carriageway counted at least this
        # flow [veh/h] is implausible (a stuck or cut loop; at 600 veh/h over 60 s a healthy 2-lane
        # station sees nobody with probability ~e^-10) and is not fused.  The NIS down-weighting alone
        # cannot catch it: a station stuck at zero agrees with an empty prior, and once the filter has
        # followed it down the healthy station of the segment is the one that disagrees (air_ground_watch
        # seed 1, loops only: a segment at 60 veh/km/lane estimated at 1).  None: off.
        zero_check_vph: float | None = Field(600.0, gt=0.0)
        # file of the map between segment-mean and station-scale density (``corridor.traffic.macro.station_map``):
        # loop densities are taken to the segment mean (g^-1) before they are fused; None: as read
        station_map: str | None = None
        filter: FusionParams = Field(default_factory=FusionParams)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.link: Any = None
        self.kf: SegmentFilter | None = None
        self._seen_loops: dict[str, float] = {}
        self.uav_received = 0
        self.uav_age_sum_s = 0.0
        self.uav_age_max_s = 0.0
        self.n = 0
        self.zero_rejected = 0  # station intervals rejected by the zero test
        self.zero_stations: set[str] = set()

    def setup(self, ctx: RunContext) -> None:
        self.n = len(self.det.interchanges)
        m = self.params.segments_per_link
        self.kf = SegmentFilter(2 * self.n * m, self.params.filter)
        self.lanes = int(ctx.snapshot.road.tables.landmarks.lanes)  # loops average over the lanes
        self._speed = loop_speed_kmh  # space-mean speed of a station, as the direct mapping computes it
        self.station_map = None
        if self.params.station_map:
            self.station_map = load_station_map(self.params.station_map)

    def station_segment(self, key: str, side: str) -> int:
        """Segment a loop station informs: downstream of merge k -> the first segment of link k; upstream
        of merge k -> the last segment of the link ending there."""
        d = "ccw" if key.startswith("ccw") else "cw"
        dirn, k, m = DIRECTIONS.index(d), int(key[len(d):]), self.params.segments_per_link
        if side == "down":
            return (dirn * self.n + k) * m
        hop = 1 if dirn == 0 else -1
        return (dirn * self.n + (k - hop) % self.n) * m + m - 1

    def tick(self, ctx: RunContext) -> None:
        self.refresh(ctx.t)

    def refresh(self, t_s: float) -> None:
        kf = self.kf
        kf.predict(t_s)
        fresh = []
        for key, m in self.det.latest.items():
            if m.t_loops <= self._seen_loops.get(key, -math.inf):
                continue
            self._seen_loops[key] = m.t_loops
            fresh.append(m)
        readings = []
        for key, side, m in self._plausible(fresh):
            r = self._loop(f"{key}/{side}", self.station_segment(key, side), m, side)
            if r is not None:
                readings.append(r)
        if readings:
            kf.update_loops(readings)
        if self.link is not None and self.link.link is not None:
            for _t_recv, _src, _t_sent, msg in self.link.take_estimates():
                t_meas = msg.time_boot_ms / 1000.0
                v = 3.6 * msg.speed if math.isfinite(msg.speed) else math.nan
                v_var = 3.6**2 * msg.speed_var if math.isfinite(msg.speed_var) else math.nan
                area = msg.observed_length / 1000.0 * self.lanes  # [km lane] the stretch the camera counted
                kf.update_uav(int(msg.segment), t_meas, msg.density, msg.density_var, v, v_var, area)
                age = max(t_s - t_meas, 0.0)
                self.uav_received += 1
                self.uav_age_sum_s += age
                self.uav_age_max_s = max(self.uav_age_max_s, age)

    def _plausible(self, fresh: list[RampMeasurement]) -> list[tuple[str, str, RampMeasurement]]:
        """The (key, side, measurement) station intervals that pass the zero test (see ``zero_check_vph``)."""
        out = [(m.key, side, m) for m in fresh for side in ("down", "up")]
        limit = self.params.zero_check_vph
        if limit is None:
            return out
        flows: dict[str, list[float]] = {}
        for _, side, m in out:
            if m.ok_down if side == "down" else m.ok_up:
                flows.setdefault(m.direction, []).append(m.flow_down_vph if side == "down" else m.flow_up_vph)
        busy = {d: float(np.median(f)) >= limit for d, f in flows.items()}
        kept = []
        for key, side, m in out:
            ok, flow, occ = ((m.ok_down, m.flow_down_vph, m.occupancy_down_pct) if side == "down"
                             else (m.ok_up, m.flow_up_vph, m.occupancy_up_pct))
            if ok and flow <= 0.0 and occ <= 0.0 and busy.get(m.direction, False):
                self.zero_rejected += 1
                self.zero_stations.add(f"{key}/{side}")
                continue
            kept.append((key, side, m))
        return kept

    def _loop(self, station: str, i: int, m: RampMeasurement, side: str) -> tuple[str, int, float, float] | None:
        """(station, segment, density, speed) of one station's interval; None on dropout (nothing came)."""
        ok = m.ok_down if side == "down" else m.ok_up
        if not ok:
            return None
        occ, flow, spd = ((m.occupancy_down_pct, m.flow_down_vph, m.speed_down_mps) if side == "down"
                          else (m.occupancy_up_pct, m.flow_up_vph, m.speed_up_mps))
        L = self.params.vehicle_length_m
        rho = occ * 10.0 / L
        if self.station_map is not None:
            rho = float(self.station_map.to_segment(np.array([rho]))[0])
        return station, i, rho, self._speed(occ, flow, spd, self.lanes, L)

    def densities(self) -> np.ndarray:
        """[n_seg] fused density [veh/km/lane]."""
        return self.kf.rho.copy()

    def speeds_kmh(self) -> np.ndarray:
        """[n_seg] fused space-mean speed [km/h] (nan: never measured)."""
        return self.kf.v.copy()

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        kf = self.kf
        weights = [kf.station_weight(s) for s in kf.health] if kf else []
        return {"fusion_uav_estimates": self.uav_received,
                "fusion_uav_aoi_mean_s": self.uav_age_sum_s / self.uav_received if self.uav_received else math.nan,
                "fusion_uav_aoi_max_s": self.uav_age_max_s if self.uav_received else math.nan,
                "fusion_stations_downweighted": int(sum(w < 0.5 for w in weights)),
                "fusion_stations_zero": len(self.zero_stations), "fusion_zero_rejected": self.zero_rejected}
