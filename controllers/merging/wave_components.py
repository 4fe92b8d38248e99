"""Connected vehicles that dampen merge waves (``v2x_wave_damping``), over a lossy V2X channel.

Per road step, in pipeline order:
1. *sense*: a roadside unit (RSU) at the merge measures, with noisy sensors, the speed of every vehicle
   on the highway in cells of ``cell_m`` from ``zone_before_m`` before the merge to its end, and the
   arrival time at the merge of every vehicle on the ramp;
2. *communicate*: every ``rsu_period_s`` it broadcasts both (one message) to the connected highway
   vehicles in the zone, over the scenario's channel (range, latency, loss);
3. *decide*: each connected highway vehicle with a fresh message drives the FollowerStopper
   (``wave_damping.follower_stopper``) towards the speed the RSU reports for the road ahead of it
   (jam absorption), capped so that it reaches the merge a headway behind a ramp vehicle it would
   otherwise meet there (gap creation); the speed change per step is bounded (``a_max_mps2``,
   ``b_comfort_mps2``: Flow's RL vehicles' 1.5 m/s²) and passes the safety layer
   (``safety_layer.safe_accel``: the Gipps / RSS bound to its physical leader, sensed on board).  The
   layer counts on the braking the vehicle can deliver: commanded in speed mode 27 SUMO executes a
   commanded braking up to the type's ``emergencyDecel`` (in mode 31 only up to its ``decel``), so
   ``b_ego`` is at most the smallest of those of the connected flows' types, and the reaction time at
   least the period a command is held (a 6 m/s² bound with 2 m/s² brakes let
   commanded vehicles run into their leaders: 5.9 collisions a run at 33 % with the calibrated humans).
   Without a fresh message (older than ``stale_after_s``) the vehicle is handed back to its driver
   model (``Release``, counted as a fallback); past the merge it is released for good.

SUMO's own safe-speed check (the vehicle type's speed mode) stays on for commanded vehicles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.channel import ChannelConfig, ChannelStats
from corridor.controllers.merging import wave_kernel as wk
from corridor.controllers.merging.components import deliverable_safety
from corridor.controllers.merging.rsu_broadcast import RsuBroadcast, newest_per_receiver, rsu_broadcast
from corridor.controllers.merging.rsu_kernel import road_ahead
from corridor.controllers.merging.safety_layer import SafetyParams, safe_accel
from corridor.controllers.merging.wave_damping import (
    StopperParams,
    follower_stopper,
    gap_speed_cap,
)
from corridor.controllers.merging.wave_kernel import ACT_COMMAND, ACT_RELEASE, HAVE_C_POW, wave_tick
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.snapshot import Role
from corridor.traffic.sumo.commands import Release, SetSpeed
from corridor.traffic.sumo.trips import NEEDS_ROAD, road_frame

RSU = "rsu"
_RAMP = int(Role.RAMP)  # a plain int: numpy compares an IntEnum member several times slower (~10 us)


def downstream_speed_floats(x_m: float, known: list[tuple[float, float]], horizon_m: float, default_mps: float) -> float:
    """``wave_damping.downstream_speed`` on the known (finite) cells as Python floats (centre [m], speed
    [m/s]), with its value: numpy's mean of fewer than 8 values sums them in order from the first."""
    vals = [v for cx, v in known if x_m < cx <= x_m + horizon_m]
    if not vals:
        return default_mps
    if len(vals) >= 8:  # numpy's pairwise sum
        return float(np.array(vals).mean())
    total = vals[0]
    for v in vals[1:]:
        total += v
    return total / len(vals)


@dataclass(frozen=True, slots=True)
class RoadAhead:
    """RSU -> connected vehicles: cell centres x [m], their mean speed [m/s] (nan: empty), ramp ETAs [s],
    and the connected vehicle asked to stop for the ramp vehicles waiting at the yield line (None: none)."""

    t_sent_s: float
    cell_x_m: np.ndarray
    cell_speed_mps: np.ndarray
    ramp_eta_s: np.ndarray
    yielder: str | None = None


class WaveDamping(Controller):
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('v2x_delivery_ratio', '1', 'Share of the roadside unit\'s messages delivered.'),
        Metric('v2x_fallbacks', '1', 'Connected vehicles handed back to their driver model because the last message was stale.'),
        Metric('v2x_commands', '1', 'Speed commands sent to connected vehicles.'),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "peer:road"  # [s] every road step
    compiled_tick: ClassVar[bool] = True  # the plain law may run as one compiled call (wave_kernel.wave_tick)
    measure_compiled: ClassVar[bool] = True  # ... its measurement too (False: _measure's message, kept as an object)

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        channel: str = "v2x"  # a key of the scenario's `channels` (defaults if absent)
        rsu_period_s: float = Field(0.5, gt=0)  # [s] between RSU broadcasts
        cell_m: float = Field(50.0, gt=0)  # [m]
        zone_before_m: float = Field(300.0, gt=0)  # [m] RSU coverage (and control) before the merge
        horizon_m: float = Field(150.0, gt=0)  # [m] the road ahead a vehicle takes its speed from
        u_min_mps: float = Field(5.0, ge=0)  # [m/s] lowest reference speed
        u_max_mps: float = Field(30.0, gt=0)  # [m/s] highest (the speed limit)
        free_above_mps: float | None = Field(18.0, gt=0)  # [m/s] cells at least this fast count as free
        #   (u_max): the vehicle reacts to waves only, not to the ordinary spread of speeds (None: off)
        a_max_mps2: float = Field(1.5, gt=0)  # [m/s²]
        b_comfort_mps2: float = Field(1.5, gt=0)  # [m/s²] the law's own braking (the layer may brake harder)
        gap_headway_s: float = Field(0.0, ge=0)  # [s] gap created behind a merging vehicle (0: none).  Off
        #   by default: on flow_merge with the calibrated humans (4 seeds, 10 %) 1.5 s cost 5.5 m/s of
        #   average speed against 2.0 m/s without it (a ramp vehicle waiting at the yield line slows
        #   the connected vehicle to a crawl, and the humans behind it break down)
        gap_zone_m: float = Field(200.0, ge=0)  # [m] gap creation only this close to the merge
        # courtesy stop: while ramp vehicles wait at the yield line, the RSU asks one connected highway
        # vehicle (the nearest that can stop at ``yield_stop_m`` before the merge with ``b_comfort``) to
        # stop there and hold for up to ``yield_hold_s``, so the waiting ramp vehicles can go.  SUMO's
        # drivers at the yield line take no gap a moving stream offers (flow_merge, calibrated humans:
        # none merged in 300 s, and easing off to open 3-10 s gaps let none in either)
        yield_stop_m: float = Field(0.0, ge=0)  # [m] stop point before the merge (0: off)
        yield_zone_m: float = Field(300.0, gt=0)  # [m] vehicles this close to the merge may be asked
        yield_hold_s: float = Field(10.0, ge=0)  # [s] longest hold once stopped
        waiting_m: float = Field(30.0, ge=0)  # [m] a ramp vehicle this close to the merge and
        waiting_mps: float = Field(2.0, ge=0)  # [m/s]  slower than this waits at the yield line
        stale_after_s: float = Field(1.0, gt=0)  # [s]
        release_after_m: float = Field(0.0, ge=0)  # [m] past the merge point a vehicle is handed back
        command_speed_mode: int = Field(27, ge=0, le=31)  # SUMO speed mode of commanded vehicles: 27 =
        #   all checks but the type's comfortable decel (bit 2), so a commanded braking is executed up to
        #   the type's emergency decel; 31 keeps the decel limit (the layer then counts on decel only)
        sensor_noise_mps: float = Field(0.5, ge=0)  # [m/s] RSU speed sensing
        stopper: StopperParams = Field(default_factory=StopperParams)
        safety: SafetyParams = Field(default_factory=SafetyParams)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.chan_cfg = scenario.channels.get(params.channel, ChannelConfig())
        self.latest: dict[str, RoadAhead] = {}  # vehicle -> newest RSU message received
        self.controlled: set[str] = set()
        self.fallbacks = 0
        self.commands_sent = 0
        self._next_rsu_s = 0.0
        self._yield: tuple[str, float | None] | None = None  # (the yielding vehicle, when it stopped [s])
        self._yielded: set[str] = set()  # vehicles that have held once (never asked twice)
        self._partnered: set[str] = set()  # vehicles whose law's command a subclass caps (_capped); none here

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        lm = road_frame(ctx).tables.landmarks
        if not hasattr(lm, "merge_x"):
            raise ValueError(f"{self.name}: wave damping needs the flow_merge network (a merge_x), not {lm.kind!r}")
        self.lm = lm
        self.merge_x, self.end_x = float(lm.merge_x), float(lm.mainline_end_x)
        self.cos_ramp = math.cos(math.radians(lm.ramp_angle_deg))
        self.cells = np.arange(self.merge_x - self.p.zone_before_m, self.end_x, self.p.cell_m) + 0.5 * self.p.cell_m
        # the general channel's broadcasts, copy for copy, without its per-call bookkeeping (no age of
        # information: the controller reports the delivery ratio only)
        self.channel = rsu_broadcast(self.chan_cfg, ctx.rng(f"{self.name}.channel"), ctx.duration, RSU)
        self._members: set[str] = set()  # the channel's receivers
        self._member_list: list[str] = []  # the compiled tick's: by row, and their nodes (_update_members)
        self._nodes = np.empty(0, dtype=np.int64)
        self._rsu_pos = np.array([self.merge_x, 0.0, 0.0])  # [m]
        self._cell_base = float(self.cells[0] - 0.5 * self.p.cell_m)  # [m] the first cell's start
        self._cells_of: tuple[RoadAhead | None, list[tuple[float, float]]] = (None, [])  # message -> its known
        #   cells (centre, speed; free ones at u_max)
        self.sensor_rng = ctx.rng(f"{self.name}.sensor")
        self._ramp_lane = np.zeros(0, dtype=bool)
        self.safety = deliverable_safety(self.p.safety, ctx.scenario, self.p.command_speed_mode, self.period)
        p = self.p
        # the compiled tick covers the plain law (no courtesy stop, no gap creation, Bernoulli loss, fewer
        # than 8 cells in a road ahead: summed in order); the rest runs _communicate and _decide
        self.compiled = (HAVE_C_POW and self.compiled_tick and isinstance(self.channel, RsuBroadcast)
                         and p.yield_stop_m == 0 and p.gap_headway_s == 0 and p.horizon_m < 6.0 * p.cell_m)
        if self.compiled:
            self._wave_cfg = wk.cfg_array(p, self.safety, self._cell_base, self.merge_x + p.release_after_m, self.period,
                                      self.chan_cfg, ctx.duration if ctx.duration is not None else math.inf)
            self._cnt = np.zeros(wk.N_CNT, dtype=np.int64)
            self._cnt[wk.K_MAX_IN_FLIGHT] = self.chan_cfg.max_in_flight
            self._latest_row = np.full(16, -1, dtype=np.int64)  # node -> its newest message (-1: none)
            self._msg_t, self._msg_cells = np.empty(64), np.empty((64, len(self.cells)))  # by send order
            self._pend_node, self._pend_t, self._pend_msg = np.empty(64, dtype=np.int64), np.empty(64), np.empty(
                64, dtype=np.int64)  # the copies in flight, in send order
            self._out = (np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64), np.empty(64))
            self._none = np.empty(0)
            self._msg_objs: list[RoadAhead] = []  # by send order, when measured in Python (measure_compiled False)

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        s = self._sense(ctx)
        if s is None:
            return
        if self.compiled:
            ctx.commands.extend(self._tick_compiled(ctx.t, s))
            return
        self._communicate(ctx.t, s)
        ctx.commands.extend(self._decide(ctx.t, s))

    def _sense(self, ctx: RunContext) -> dict[str, Any] | None:
        snap, r = ctx.snapshot, ctx.snapshot.road
        if r is None or len(r) == 0:
            return None
        sl, tb = r.sl, r.tables
        if len(self._ramp_lane) < tb.n_lanes:
            self._ramp_lane = np.array([self.lm.is_ramp_lane(n) for n in tb.lane_names], dtype=bool)
        pos, size = snap.position[sl], snap.size[sl]
        front = pos[:, 0] + 0.5 * size[:, 0] * np.cos(snap.heading[sl])
        return {"ids": snap.ids[sl].tolist(), "front": front, "length": size[:, 0], "speed": snap.speed[sl],
                "on_ramp": self._ramp_lane[r.lane], "ramp": tb.role[r.uid] == _RAMP,
                "connected": tb.connected[r.uid], "pos": pos}

    def _communicate(self, t: float, s: dict[str, Any]) -> None:
        """RSU broadcast to the connected highway vehicles in the zone; newest message per vehicle kept."""
        ids = s["ids"]
        rows = np.flatnonzero(self._receivers(s))
        members = [ids[k] for k in rows.tolist()]
        member_set = set(members)
        if member_set != self._members:  # the channel's receivers change only with the membership
            # sorted: the attach order decides which receiver gets which loss draw, and a set's order
            # follows the string hash (PYTHONHASHSEED), which differs from process to process
            for vid in sorted(member_set - self._members):
                self.channel.attach(vid)
            for vid in sorted(self._members - member_set):
                self.channel.detach(vid)
                self.latest.pop(vid, None)
            self._members = member_set
        if t + 1e-9 >= self._next_rsu_s:
            self._next_rsu_s += self.p.rsu_period_s
            # a broadcast to no receiver draws nothing and takes no send order: the measurement is
            # skipped when nothing else depends on it (_unheard)
            if members or not self._unheard(s):
                self.channel.send(t, self._measure(t, s), self._rsu_pos, members, s["pos"][rows])
        newest_per_receiver(self.channel.deliver(t), self.channel.names, self.latest)

    def _tick_compiled(self, t: float, s: dict[str, Any]) -> list[Any]:
        """``_communicate`` and ``_decide`` (the plain law) with one compiled call (``wave_kernel.wave_tick``):
        the same draws, channel, messages, commands and events; Python keeps the names, the membership,
        the draws, the commands and the events."""
        ids, ch = s["ids"], self.channel
        assert isinstance(ch, RsuBroadcast)
        rows = self._receiver_rows(s)
        members = [ids[k] for k in rows.tolist()]
        if members != self._member_list:  # the same receivers in the same rows: the same set and nodes
            self._update_members(members)
        m, cnt = len(members), self._cnt
        send = t + 1e-9 >= self._next_rsu_s
        if send:
            self._next_rsu_s += self.p.rsu_period_s
        if m:
            self._make_room(int(cnt[wk.K_SEQ]) + 1, int(cnt[wk.K_N_PEND]) + m)
        out_row, out_act, out_v = self._out
        if len(out_row) < len(ids):
            self._out = out_row, out_act, out_v = (np.empty(2 * len(ids), dtype=np.int64),
                                                   np.empty(2 * len(ids), dtype=np.int64), np.empty(2 * len(ids)))
        k = self._compiled_step(t, s, send, rows)
        cmds: list[Any] = []
        capped, mode, controlled = self._partnered, self.p.command_speed_mode, self.controlled
        for j, act, v in zip(out_row[:k].tolist(), out_act[:k].tolist(), out_v[:k].tolist(), strict=True):
            vid = ids[j]
            if act == ACT_COMMAND:
                cmds.append(SetSpeed(vid, self._capped(t, s, j, vid, v) if vid in capped else v, mode))
                controlled.add(vid)
                self.commands_sent += 1
                continue
            if act != ACT_RELEASE and vid in self.controlled:  # no fresh message
                self.fallbacks += 1
                self.events.emit(t, self.name, "fallback", f"{vid}: stale V2X information, own driver model")
            self._release(vid, cmds)
        self._decide_more(t, s, cmds)
        return cmds

    def _compiled_step(self, t: float, s: dict[str, Any], send: bool, rows: np.ndarray) -> int:
        """The compiled tick's call (``wave_kernel.wave_tick``) with its draws, for the receivers at ``rows``
        (``send``: a broadcast time); the commands' count in ``self._out``."""
        ch = self.channel
        assert isinstance(ch, RsuBroadcast)
        m = len(rows)
        noise, u, cells_in = self._none, self._none, self._none
        if send:
            if self.measure_compiled:
                noise = self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, len(s["speed"]))  # measured or not
            else:  # the message as _communicate makes it (measured whoever listens: _unheard is False)
                msg = self._measure(t, s)
                cells_in = msg.cell_speed_mps
                if m:
                    self._msg_objs.append(msg)  # its row: the send order
            if m:
                u = ch._rng.random(2 * m)  # the channel's loss, then delay uniforms
        out_row, out_act, out_v = self._out
        return wave_tick(t, self._wave_cfg, self.cells, s["front"], s["speed"], s["length"], s["on_ramp"], s["ramp"],
                         s["connected"], s["pos"], send, self.measure_compiled, noise, cells_in, rows, self._nodes, u,
                         self._rsu_pos, ch._attached, self._latest_row, self._msg_t, self._msg_cells, self._pend_node,
                         self._pend_t, self._pend_msg, self._cnt, out_row, out_act, out_v)

    def _update_members(self, members: list[str]) -> None:
        """The compiled tick's receivers are now ``members`` (by row): attach and detach by the membership
        (in name order, see ``_communicate``), their nodes in that order."""
        ch = self.channel
        assert isinstance(ch, RsuBroadcast)
        member_set = set(members)
        if member_set != self._members:
            for vid in sorted(member_set - self._members):
                ch.attach(vid)
            for vid in sorted(self._members - member_set):
                ch.detach(vid)
                self._latest_row[ch.index[vid]] = -1
            self._members = member_set
            if len(self._latest_row) < len(ch._attached):
                self._latest_row = np.concatenate([self._latest_row,
                                                   np.full(len(ch._attached) - len(self._latest_row), -1)])
        self._member_list = members
        self._nodes = np.array([ch.index[r] for r in members], dtype=np.int64)

    def _receiver_rows(self, s: dict[str, Any]) -> np.ndarray:
        """The compiled tick's receivers: the rows of ``_receivers``' mask (a subclass may find them otherwise)."""
        return np.flatnonzero(self._receivers(s))

    def _capped(self, t: float, s: dict[str, Any], k: int, vid: str, v_cmd: float) -> float:
        """The compiled tick's command [m/s] for vehicle ``vid`` (row ``k``) whose law gives ``v_cmd``
        (a subclass caps it as its ``_speed`` does; called only for the vehicles in ``_partnered``)."""
        return v_cmd

    def _decide_more(self, t: float, s: dict[str, Any], cmds: list[Any]) -> None:
        """The commands a subclass's ``_decide`` adds after the law's (the compiled tick's hook)."""

    def _latest_of(self, vid: str) -> RoadAhead | None:
        """The newest message ``vid`` received (None: none), on either path (the compiled tick keeps the
        messages by row, the objects when measured in Python)."""
        if not self.compiled:
            return self.latest.get(vid)
        node = self.channel.index.get(vid)
        q = -1 if node is None else int(self._latest_row[node])
        return self._msg_objs[q] if q >= 0 else None

    def _make_room(self, n_msg: int, n_pend: int) -> None:
        """The compiled tick's arrays hold ``n_msg`` messages and ``n_pend`` copies in flight (doubled)."""
        if len(self._msg_t) < n_msg:
            n = max(n_msg, 2 * len(self._msg_t))
            self._msg_t = np.concatenate([self._msg_t, np.empty(n - len(self._msg_t))])
            self._msg_cells = np.concatenate([self._msg_cells, np.empty((n - len(self._msg_cells), len(self.cells)))])
        if len(self._pend_node) < n_pend:
            n, c = max(n_pend, 2 * len(self._pend_node)), len(self._pend_node)
            self._pend_node = np.concatenate([self._pend_node, np.empty(n - c, dtype=np.int64)])
            self._pend_t = np.concatenate([self._pend_t, np.empty(n - c)])
            self._pend_msg = np.concatenate([self._pend_msg, np.empty(n - c, dtype=np.int64)])

    def _channel_stats(self) -> ChannelStats:
        """The channel's statistics (the compiled tick counts them itself)."""
        if not self.compiled:
            return self.channel.stats()
        c = self._cnt.tolist()
        return ChannelStats.counted(c[wk.K_SENT], c[wk.K_DELIVERED], c[wk.K_LOST], c[wk.K_OOR], c[wk.K_LATE],
                                    c[wk.K_OVERFLOW])

    def _receivers(self, s: dict[str, Any]) -> np.ndarray:
        """Mask of the vehicles that listen to the RSU: the connected highway vehicles in the zone."""
        return (s["connected"] & ~s["ramp"] & (s["front"] > self.merge_x - self.p.zone_before_m)
                & (s["front"] < self.merge_x + self.p.release_after_m))

    def _unheard(self, s: dict[str, Any]) -> bool:
        """What a measurement nobody receives leaves behind, done without the measurement: its sensor
        draws (the same calls on the sensor stream).  False: the measurement has effects of its own
        (the courtesy stop's choice and events), it is made in full."""
        if self.p.yield_stop_m > 0:
            return False
        self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, len(s["speed"]))
        return True

    def _measure(self, t: float, s: dict[str, Any]) -> RoadAhead:
        """The RSU's noisy view: mean speed per cell on the highway, ramp vehicles' arrival times."""
        noise = self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, len(s["speed"]))
        v = np.maximum(s["speed"] + noise, 0.0)
        if self.p.yield_stop_m > 0:  # the courtesy stop reads the ramp vehicles waiting at the yield line
            cell_speed, eta, dist, v_ramp = self._road_ahead_numpy(t, s["front"], v, s["on_ramp"])
            waiting = bool(np.any((dist < self.p.waiting_m) & (v_ramp < self.p.waiting_mps)))
            return RoadAhead(t, self.cells, cell_speed, eta, self._pick_yielder(t, s, waiting))
        cell_speed = np.empty(len(self.cells))
        eta = np.empty(int(np.count_nonzero(s["on_ramp"])))
        road_ahead(s["front"], v, s["on_ramp"], self._cell_base, self.p.cell_m, self.merge_x, self.cos_ramp, t,
                   cell_speed, eta)  # compiled: _road_ahead_numpy's bits
        return RoadAhead(t, self.cells, cell_speed, eta, self._pick_yielder(t, s, False))

    def _road_ahead_numpy(self, t: float, front: np.ndarray, v: np.ndarray, on_ramp: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Mean speed per cell of the highway line, the ramp vehicles' arrival times at the merge, their
        distances along the ramp and their speeds (``rsu_kernel.road_ahead`` computes the first two)."""
        line = ~on_ramp
        k = np.floor((front[line] - self._cell_base) / self.p.cell_m).astype(int)
        ok = (k >= 0) & (k < len(self.cells))
        k_ok = k[ok]
        total = np.bincount(k_ok, weights=v[line][ok], minlength=len(self.cells))
        count = np.bincount(k_ok, minlength=len(self.cells))
        cell_speed = total / np.where(count > 0, count, np.nan)  # empty cells: nan (no 0 / 0)
        dist = (self.merge_x - front[on_ramp]) / self.cos_ramp  # [m] along the ramp
        v_ramp = v[on_ramp]
        eta = t + np.maximum(dist, 0.0) / np.maximum(v_ramp, 1.0)
        return cell_speed, eta, dist, v_ramp

    def _pick_yielder(self, t: float, s: dict[str, Any], waiting: bool) -> str | None:
        """The connected highway vehicle asked to stop for the waiting ramp vehicles (courtesy stop):
        the one holding already, until no ramp vehicle waits or it held ``yield_hold_s``; else the
        nearest to the stop point that can still stop there comfortably."""
        p = self.p
        if p.yield_stop_m <= 0 or not waiting:
            if self._yield is not None:
                self._yielded.add(self._yield[0])
            self._yield = None
            return None
        ids = s["ids"]
        room = self.merge_x - p.yield_stop_m - s["front"]  # [m] to the stop point
        if self._yield is not None:
            vid, t_stop = self._yield
            k = ids.index(vid) if vid in ids else -1
            if k >= 0 and room[k] > -1.0 and (t_stop is None or t - t_stop < p.yield_hold_s):
                if t_stop is None and s["speed"][k] < 0.5:
                    self._yield = (vid, t)
                return vid
            self._yielded.add(vid)
            self._yield = None
        v = s["speed"]
        ok = (s["connected"] & ~s["ramp"] & ~s["on_ramp"] & (room > 0)
              & (room < p.yield_zone_m - p.yield_stop_m) & (v * v <= 2.0 * p.b_comfort_mps2 * room))
        cand = [k for k in np.flatnonzero(ok) if ids[k] not in self._yielded]
        if not cand:
            return None
        k = min(cand, key=lambda j: room[j])
        self._yield = (ids[k], None)
        self.events.emit(t, self.name, "courtesy_stop", f"{ids[k]}: stop {p.yield_stop_m:.0f} m before the merge "
                         "for the ramp vehicles waiting at the yield line", vehicle=ids[k])
        return ids[k]

    def _decide(self, t: float, s: dict[str, Any]) -> list[Any]:
        cmds: list[Any] = []
        ids, front = s["ids"], s["front"]
        line = np.flatnonzero(~s["on_ramp"])
        order = line[np.argsort(front[line], kind="stable")]  # the vehicles on the highway line, rear first
        ord_l, n = order.tolist(), len(order)
        front_l, speed_l, length_l = front.tolist(), s["speed"].tolist(), s["length"].tolist()
        x_release = self.merge_x + self.p.release_after_m
        for j in np.flatnonzero((s["connected"] & ~s["ramp"])[order]).tolist():  # the connected ones
            k = ord_l[j]
            vid = ids[k]
            if front_l[k] >= x_release:
                self._release(vid, cmds)
                continue
            msg = self.latest.get(vid)
            if msg is None or t - msg.t_sent_s > self.p.stale_after_s:
                if vid in self.controlled:
                    self.fallbacks += 1
                    self.events.emit(t, self.name, "fallback", f"{vid}: stale V2X information, own driver model")
                self._release(vid, cmds)
                continue
            lead = ord_l[j + 1] if j + 1 < n else None
            gap = front_l[lead] - length_l[lead] - front_l[k] if lead is not None else math.inf
            v_lead = speed_l[lead] if lead is not None else self.p.u_max_mps
            cmds.append(SetSpeed(vid, self._speed(t, msg, front_l[k], speed_l[k], gap, v_lead, vid),
                                 self.p.command_speed_mode))
            self.controlled.add(vid)
            self.commands_sent += 1
        return cmds

    def _speed(self, t: float, msg: RoadAhead, x: float, v: float, gap: float, v_lead: float, vid: str = "") -> float:
        """FollowerStopper to the road ahead's speed, the gap cap, bounded change, the safety layer."""
        p = self.p
        if self._cells_of[0] is not msg:  # the known cells as the law reads them: once per message
            cells = msg.cell_speed_mps
            if p.free_above_mps is not None:
                cells = np.where(cells >= p.free_above_mps, p.u_max_mps, cells)
            self._cells_of = (msg, [(cx, cv) for cx, cv in zip(msg.cell_x_m.tolist(), cells.tolist(), strict=True)
                                    if math.isfinite(cv)])
        u = downstream_speed_floats(x, self._cells_of[1], p.horizon_m, p.u_max_mps)
        dist = self.merge_x - x
        if p.gap_headway_s > 0 and dist < p.gap_zone_m:
            u = min(u, gap_speed_cap(dist, v, t, msg.ramp_eta_s, p.gap_headway_s, p.u_min_mps))
        u = min(max(u, p.u_min_mps), p.u_max_mps)  # np.clip's value, without its call
        v_cmd = follower_stopper(gap, v, v_lead, u, p.stopper) if math.isfinite(gap) else u
        if msg.yielder is not None and msg.yielder == vid:  # courtesy stop at the stop point
            v_cmd = min(v_cmd, math.sqrt(2.0 * p.b_comfort_mps2 * max(dist - p.yield_stop_m, 0.0)))
        a = min(max((v_cmd - v) / self.period, -p.b_comfort_mps2), p.a_max_mps2)
        if math.isfinite(gap):
            a = safe_accel(gap, v, v_lead, a, self.safety)
        return max(0.0, v + a * self.period)

    def _release(self, vid: str, cmds: list[Any]) -> None:
        if vid in self.controlled:
            self.controlled.discard(vid)
            cmds.append(Release(vid))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        st = self._channel_stats()
        return {"v2x_delivery_ratio": st.delivery_ratio, "v2x_fallbacks": self.fallbacks,
                "v2x_commands": self.commands_sent}
