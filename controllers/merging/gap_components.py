"""Connected ramp vehicles that cross Flow's merge junction at speed on a roadside unit's reservation
(``v2x_merge_gaps``), over a lossy V2X channel.

Why: SUMO's junction model lets a ramp vehicle on the minor link lead an approaching highway vehicle
only if that vehicle arrives more than ``jmTimegapMinor`` (1 s) after the ramp vehicle leaves the
junction and ``MSLink::unsafeMergeSpeeds`` does not hold (the ramp vehicle's leave speed²/decel must
exceed the highway vehicle's arrival-speed-when-braking²/decel).  SUMO's ramp drivers slow to a few
m/s at the minor link whatever the traffic, so they start from rest, and from rest the next highway
vehicle must be able to stop short of the junction: ~150 m away at 24 m/s with the calibrated humans'
2 m/s².  A 1.8 s-headway stream never offers that.  A ramp vehicle that arrives at speed needs only
time gaps: about 2 s after the highway vehicle ahead and 2 s before the one behind.

What (per road step, on top of the wave-damping law of ``v2x_wave_damping`` for connected highway
vehicles):
1. *coordinate* (RSU, every ``rsu_period_s``, noisy sensing): every connected ramp vehicle with no
   unconnected vehicle ahead of it on the ramp (``pair_queue_head_only``), in its order on the ramp,
   gets a follower and a slot: its time at the junction, ``ramp_time_gap_s`` after
   the predicted arrival of the highway vehicle ahead of the follower and no earlier than it can make
   it.  The follower is the first highway vehicle that can arrive ``open_time_gap_s`` later: a
   connected *partner*, which then opens the gap (never slower than ``partner_min_speed_mps``), or a
   human whose predicted arrival already leaves the gap.  A slot holds once given; a pair whose ramp
   vehicle cannot make its slot, or whose follower no longer fits, is dropped before the run starts.
2. *decide*: the ramp vehicle holds a cruise speed and accelerates to the crossing speed as late as
   possible so as to reach the junction at its slot at speed (``arrival_accel``); without a slot it
   waits where its run-up still fits, not at the yield line.  ``commit_m`` plus its braking distance
   before the line it takes the go / no-go: it commits if its virtual leader (the highway vehicle
   ahead of the slot, projected onto the ramp) is ahead with a safe gap and the follower can stay
   behind it braking comfortably, and then crosses in ``reserved_speed_mode`` (the reservation, not
   the yield sign, keeps the gap); if the leader's gap closes it drops back to SUMO's yield rule.  The
   partner arrives no earlier than its slot and keeps a safe gap behind the projected ramp vehicle on
   its run.  Every command passes the safety layer (``safety_layer.safe_accel``) against the physical
   leader (sensed on board) and the virtual one; a vehicle whose newest message is older than
   ``stale_after_s`` is handed back to its driver model.

Gap made from ahead (``lead_close_up``, off by default; variant ``cal_all10_lead``): when the highway vehicle
ahead of a slot is connected, that *leader* closes up to its own leader (a constant-time-gap ACC law,
``lead_time_gap_s``) and the ramp vehicle crosses ``lead_ramp_gap_s`` behind it; the follower, human or
connected, qualifies at its own speed (nobody behind slows).  The partner-slows pairing above is the fallback
when no such slot is found.

Measured on ``scenarios/flow_merge.yaml`` (variant ``cal_all10_ramp``): docs/guide/flow-merge.md.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import Field

from corridor.controllers.merging.gap_kernel import (
    HAVE_C_POW,
    MIN_CROSS_SPEED_MPS,
    ST_SLOT,
    gap_tick,
    partner_cap,
    plan_slots,
    ramp_cfg_array,
    ramp_command,
    tick_rows,
)
from corridor.controllers.merging.gap_kernel import cfg_array as plan_cfg
from corridor.controllers.merging.rsu_broadcast import RsuBroadcast
from corridor.controllers.merging.safety_layer import safe_accel
from corridor.controllers.merging.trajectory import time_to_go
from corridor.controllers.merging.wave_components import RSU, RoadAhead, WaveDamping
from corridor.engine import Metric, RunContext
from corridor.traffic.sumo.commands import SetSpeed

K_SPEED = 0.7  # [1/s] gain of the speed hold of an unpaired ramp vehicle


class Slot(NamedTuple):
    """The RSU's plan for one pair: when the ramp vehicle is to reach the junction [s] and its partner no
    earlier than [s]; the ramp vehicle's virtual leader (the highway vehicle ahead of the partner) and
    the partner, as the RSU measured them (x [m] on the highway, speed [m/s], length [m]; None: none).
    A named tuple: made for every pair at every broadcast (a frozen dataclass's ``__init__`` cost ~3x)."""

    t_ramp_s: float
    t_partner_s: float
    lead: tuple[float, float, float] | None
    partner: tuple[float, float, float]
    ramp: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class MergePlan(RoadAhead):
    """``RoadAhead`` plus the RSU's slots (by ramp vehicle and by partner) and the speed [m/s] to cross at."""

    slots: dict[str, Slot] = field(default_factory=dict)
    partners: dict[str, str] = field(default_factory=dict)  # partner -> the ramp vehicle it lets in
    cross_speed_mps: float = 15.0
    leaders: dict[str, str] = field(default_factory=dict)  # connected leader -> the ramp vehicle behind it
    #   (``lead_close_up``: it closes up to its own leader)


def arrival_accel(dist_m: float, v_mps: float, time_s: float, v_cross: float, accel: float, brake: float) -> float:
    """Acceleration [m/s²] now towards reaching ``dist_m`` ahead in ``time_s`` at ``v_cross``: hold a
    cruise speed, then accelerate at ``accel`` to ``v_cross`` as late as possible.  Late (accelerating
    now would not be early) it accelerates; early and no cruise speed fits (it would cover too much
    road even at the slowest one) it slows down at ``brake``."""
    if time_s <= 0.5 or dist_m <= 0:
        return K_SPEED * (v_cross - v_mps)
    if time_to_go(dist_m, v_mps, v_cross, accel) >= time_s:
        return accel  # on time or late: the run to the line has begun
    # dist = v_c * time + (v_cross - v_c)^2 / (2 a), for v_c in [v_cross - a * time, v_cross]
    a_, b_, c_ = 1.0 / (2.0 * accel), time_s - v_cross / accel, v_cross * v_cross / (2.0 * accel) - dist_m
    disc = b_ * b_ - 4.0 * a_ * c_
    if disc < 0:
        return -brake  # early: even the slowest fitting cruise covers too much road
    v_c = (-b_ + math.sqrt(disc)) / (2.0 * a_)
    if v_c < max(v_cross - accel * time_s, 0.0) or v_c > v_cross:
        return -brake
    return K_SPEED * (v_c - v_mps)


class GapMerging(WaveDamping):
    """Wave damping for connected highway vehicles, plus RSU-paired gap creation and reserved crossings
    for connected ramp vehicles (see the module's docstring)."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        *WaveDamping.metrics,
        Metric('v2x_reserved_crossings', '1', 'Connected ramp vehicles that crossed the junction on a reservation.'),
    )

    measure_compiled: ClassVar[bool] = False  # the RSU's message carries its slots: measured in Python (_measure)

    class Params(WaveDamping.Params):
        ramp_time_gap_s: float = Field(1.5, ge=0)  # [s] the ramp vehicle's arrival after its virtual leader's
        open_time_gap_s: float = Field(2.0, ge=0)  # [s] the partner's arrival after the ramp vehicle's
        cross_speed_mps: float = Field(15.0, gt=0)  # [m/s] highest crossing speed (the ramp's curve: 15.7 m/s)
        pair_zone_m: float = Field(600.0, gt=0)  # [m] partners are chosen this close to the junction
        partner_min_speed_mps: float = Field(15.0, ge=0)  # [m/s] a partner never slows below this for its slot
        human_margin_s: float = Field(0.0, ge=0)  # [s] a human follower (a natural gap) must arrive this much later
        restart_gap_s: float = Field(5.0, ge=0)  # [s] follower gap for a ramp vehicle starting from rest
        restart_partner_speed_mps: float = Field(15.0, ge=0)  # [m/s] a partner slows to no less for a restart
        min_run_speed_mps: float = Field(3.0, ge=0)  # [m/s] slower near the stop line: a start from rest
        wait_speed_mps: float = Field(6.0, ge=0)  # [m/s] an unpaired ramp vehicle rolls at most this fast (and
        #   stops where its run-up still fits); a partner keeps a gap only behind a faster ramp vehicle
        plan_accel_mps2: float = Field(1.2, gt=0)  # [m/s²] a ramp vehicle's planned acceleration to the crossing
        commit_m: float = Field(60.0, ge=0)  # [m] the go / no-go is taken this far plus the braking distance
        #   before the stop line
        reserved_speed_mode: int = Field(0, ge=0, le=127)  # SUMO speed mode of a ramp vehicle with a
        #   reserved crossing: the RSU, not the yield sign, keeps the gap, and the safety layer (physical
        #   and virtual leader) is the only speed bound; with SUMO's safe speed on (19: 27 without the
        #   right-of-way bit) the minor link's approach rule still slowed it to a stop at the line
        ramp_sensor_noise_m: float = Field(1.0, ge=0)  # [m] RSU position sensing
        pair_queue_head_only: bool = True  # pair only connected ramp vehicles with no unconnected vehicle ahead
        #   of them on the ramp: one behind a human driver waits with it at the yield line, and a partner
        #   slowing down for it only costs the highway speed; until it is at the head it is left to its driver
        #   (False: every connected ramp vehicle paired and commanded, as before)
        # gap made from ahead (``lead_close_up``): when the highway vehicle ahead of a slot (the ramp vehicle's
        # virtual leader) is connected, it closes up to its own leader with an ACC time gap, so the gap behind
        # it grows without anyone behind slowing; the ramp vehicle, which receives that leader's state by V2X,
        # crosses ``lead_ramp_gap_s`` behind it, and the follower (human or connected) must arrive
        # ``open_time_gap_s`` after the ramp vehicle at its own speed.  The partner-slows pairing only when no
        # such slot is found.  Off: as before
        lead_close_up: bool = False
        lead_time_gap_s: float = Field(1.0, gt=0)  # [s] the leader's time gap to its own leader (ACC)
        lead_ramp_gap_s: float = Field(1.0, ge=0)  # [s] the ramp vehicle's arrival after a connected leader's
        lead_k_gap: float = Field(0.23, ge=0)  # [1/s²] the ACC law's gain on the gap error
        lead_k_speed: float = Field(0.07, ge=0)  # [1/s] ... on the speed difference (Milanés & Shladover 2014)
        # its second iteration (``lead_hold``, with ``lead_close_up``; variant ``cal_all10_lead2``): (a) a slot behind
        # a connected leader holds once given (the follower's fit checked at pairing only, with ``lead_noise_k``
        # standard deviations of the RSU's arrival-time error to spare, never against the leader's re-planned
        # arrival; the go / no-go at commit unchanged); (b) every connected highway vehicle in the pair zone
        # closes up (the ACC law above) whenever a connected ramp vehicle is on the ramp; (c) no partner slows:
        # without a slot behind a connected leader only natural gaps (any follower at its own speed); the
        # follower's time gap behind the ramp vehicle is the calibrated humans' desired one, front to front at
        # the crossing speed v: ``lead_follow_tau_s`` + ``lead_follow_gap_m`` / v.  Planned by ``_slots_py`` and
        # ``gap_kernel.plan_slots`` alike (not the fused tick), commanded on either path.  Off: as before
        lead_hold: bool = False
        lead_noise_k: float = Field(2.0, ge=0)  # [σ] the fit's margin for the RSU's arrival-time error at pairing
        lead_follow_tau_s: float = Field(1.2, ge=0)  # [s] EIDM tau of the calibrated humans (human_merge)
        lead_follow_gap_m: float = Field(7.0, ge=0)  # [m] their minGap 2 m + the ramp vehicle's length 5 m

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name, params, scenario)
        self.gp: GapMerging.Params = params
        self.pairs: dict[str, str] = {}  # ramp vehicle -> its partner on the highway
        self.leaders: dict[str, str] = {}  # ramp vehicle -> its connected virtual leader (lead_close_up)
        self.committed: set[str] = set()  # ramp vehicles crossing on their reservation
        self._t_slot: dict[str, float] = {}  # ramp vehicle -> its slot at the junction [s]
        self._dropped: set[str] = set()  # ramp vehicles that missed their slot this broadcast
        self._held: set[str] = set()  # ramp vehicles whose slot behind a connected leader holds (lead_hold)
        self._closers: list[str] = []  # connected highway vehicles closing up (lead_hold: a ramp vehicle comes)
        self._v_cross = 15.0  # [m/s] this broadcast's crossing speed (lead_hold's follower gap)
        self.reserved_crossings = 0
        self._work: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None  # _scratch
        self._no_pairs = (np.empty((0, 2), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool))  # _pair_arrays
        self._no_rows = np.empty(0, dtype=np.int64)
        # self._partnered (WaveDamping's): every vehicle named a partner in a message (the rest is not capped)
        self._row_work = (self._no_rows, self._no_rows, self._no_rows)  # _receiver_rows' (grown by doubling)
        self._n_plan = np.zeros(1, dtype=np.int64)  # gap_tick's count of plan rows

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        self.pos_rng = ctx.rng(f"{self.name}.position")
        self.cross_x = float(self.lm.past_merge_x)  # [m] where the ramp's lane joins the highway's
        self._near_cells = np.flatnonzero((self.cells < self.merge_x) & (self.cells > self.merge_x - 100.0))
        self._plan_cfg = plan_cfg(self.gp, self.merge_x, self.cross_x, self.cos_ramp, self._cell_base)  # gap_kernel's
        # the measurement and the slots in one call (compiled tick): no courtesy stop, fewer than 8 cells averaged
        self._fused = HAVE_C_POW and self.p.yield_stop_m == 0 and len(self._near_cells) < 8 and not self._hold
        self._zone = (self.merge_x - self.p.zone_before_m, self.merge_x + self.p.release_after_m)  # _receivers' bounds
        self._ramp_cfg = ramp_cfg_array(self.gp, self.safety, self.merge_x, self.period, K_SPEED)  # ramp_command's

    # ------------------------------------------------------------------ geometry
    def _projected(self, s: dict[str, Any]) -> np.ndarray:
        """x [m] of every vehicle on the highway line: a ramp vehicle's distance to the junction along
        the ramp, laid back from the junction along the highway; the others' own front x."""
        x = s["front"].copy()
        on = s["on_ramp"]
        x[on] = self.merge_x - (self.merge_x - x[on]) / self.cos_ramp
        return x

    # ------------------------------------------------------------------ communicate
    def _receivers(self, s: dict[str, Any]) -> np.ndarray:
        """The connected highway vehicles in the zone, the partners, and the connected ramp vehicles
        before the junction's end."""
        ramp = s["connected"] & s["ramp"] & (s["front"] < self.cross_x)
        out = super()._receivers(s) | ramp
        if self.pairs:  # the partners on the road (a pair is a few vehicles: their rows, not every id tested)
            row = self._rows(s)
            out[[row[c] for c in self.pairs.values() if c in row]] = True
            out[[row[c] for c in self.leaders.values() if c in row]] = True  # the connected leaders
        if self._closers:
            row = self._rows(s)
            out[[row[c] for c in self._closers if c in row]] = True  # lead_hold: the ones closing up
        return out

    def _receiver_rows(self, s: dict[str, Any]) -> np.ndarray:
        """``_receivers``' rows in one compiled pass (``gap_kernel.tick_rows``), which also keeps this tick's
        connected ramp vehicles (``s["_cramp"]``) and vehicles on the ramp (``s["_onramp"]``), as rows."""
        n = len(s["ids"])
        w = self._row_work
        if len(w[0]) < n:
            w = self._row_work = (np.empty(2 * n, dtype=np.int64), np.empty(2 * n, dtype=np.int64),
                                  np.empty(2 * n, dtype=np.int64))
        recv, cramp, onramp = w
        if self.pairs or self._closers:
            row = self._rows(s)
            partners = np.array([row[c] for c in (*self.pairs.values(), *self.leaders.values(), *self._closers)
                                 if c in row], dtype=np.int64)
        else:
            partners = self._no_rows
        n_recv, n_cramp, n_on = tick_rows(s["connected"], s["ramp"], s["on_ramp"], s["front"], self._zone[0],
                                          self._zone[1], self.cross_x, partners, recv, cramp, onramp)
        s["_cramp"], s["_onramp"] = cramp[:n_cramp].tolist(), onramp[:n_on].tolist()
        return recv[:n_recv].copy()

    def _unheard(self, s: dict[str, Any]) -> bool:
        return False  # the RSU pairs and plans slots (its state, its draws) whoever listens

    def _measure(self, t: float, s: dict[str, Any]) -> MergePlan:
        base = super()._measure(t, s)
        # a standstill before the merge measures 0 m/s: the plan's arrival times divide by the crossing speed
        v_cross = min(max(self._merge_speed(base.cell_speed_mps), MIN_CROSS_SPEED_MPS), self.gp.cross_speed_mps)
        slots = self._slots(t, s, v_cross)
        row, connected = self._rows(s), s["connected"]
        partners = {c: r for r, c in self.pairs.items() if r in slots and connected[row[c]]}
        leaders = {c: r for r, c in self.leaders.items()}
        if self._hold:  # nobody slows for a slot; every connected highway vehicle in the pair zone closes up
            partners = {}
            self._closers = self._closing(s)
            for c in self._closers:
                leaders.setdefault(c, "")
        self._partnered.update(partners)
        self._partnered.update(leaders)
        return MergePlan(base.t_sent_s, base.cell_x_m, base.cell_speed_mps, base.ramp_eta_s, base.yielder,
                         slots, partners, v_cross, leaders)

    def _merge_speed(self, cell_speed: np.ndarray) -> float:
        """[m/s] the mean measured speed of the cells in the 100 m before the merge (u_max: none known):
        ``np.mean``'s value (fewer than 8 values: summed in order from the first), on Python floats."""
        vals = [v for v in cell_speed[self._near_cells].tolist() if math.isfinite(v)]
        if not vals:
            return self.p.u_max_mps
        if len(vals) >= 8:  # numpy's pairwise sum
            return float(np.mean(vals))
        total = vals[0]
        for v in vals[1:]:
            total += v
        return total / len(vals)

    def _slots(self, t: float, s: dict[str, Any], v_cross: float) -> dict[str, Slot]:
        """``_slots_py`` in one compiled call (``gap_kernel.plan_slots``: the same values, draws and
        events); Python keeps the names, the draws and the event log."""
        if not HAVE_C_POW:
            return self._slots_py(t, s, v_cross)
        p, ids = self.gp, s["ids"]
        n = len(ids)
        x_noise = self.pos_rng.normal(0.0, p.ramp_sensor_noise_m, n)
        v_noise = self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, n)
        pairs, t_slot, has_slot = self._pair_arrays(s)
        x, v = np.empty(n), np.empty(n)
        out_pair, out_slot = np.empty((len(pairs) + n, 4), dtype=np.int64), np.empty((len(pairs) + n, 11))
        held = np.zeros(len(pairs) + n, dtype=bool)  # lead_hold: the kept pairs' in, the new ones' out
        if self._held:
            held[:len(pairs)] = [r in self._held for r in self.pairs]
        n_out = plan_slots(t, v_cross, self._plan_cfg, s["front"], s["speed"], s["length"], x_noise, v_noise,
                           s["connected"], s["ramp"], s["on_ramp"], pairs, t_slot, has_slot, x, v, out_pair, out_slot,
                           held)
        return self._slots_from(t, ids, s["connected"], len(pairs), out_pair[:n_out], out_slot[:n_out],
                                held[:n_out])

    def _compiled_step(self, t: float, s: dict[str, Any], send: bool, rows: np.ndarray) -> int:
        """``WaveDamping._compiled_step`` with ``_measure`` (the plain law's measurement and the slots) in the same
        compiled call (``gap_kernel.gap_tick``: ``measure_plan`` then ``wave_kernel.tick``): the same draws (the
        sensor's n for the cells then n for the slots, one stream; the positions'; the channel's), values and
        events (the message's, ``_plan_message``, before the commands')."""
        if not self._fused:
            return super()._compiled_step(t, s, send, rows)
        ch = self.channel
        assert isinstance(ch, RsuBroadcast)
        n, m, none = len(s["ids"]), len(rows), self._none
        noise, x_noise, u, cell_speed, eta = none, none, none, none, none
        pairs, t_slot, has_slot = self._no_pairs
        if send:
            noise = self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, 2 * n)  # the cells' draws, then the slots'
            x_noise = self.pos_rng.normal(0.0, self.gp.ramp_sensor_noise_m, n)
            pairs, t_slot, has_slot = self._pair_arrays(s)
            if m:
                u = ch._rng.random(2 * m)  # the channel's loss, then delay uniforms
            on = s.get("_onramp")  # this tick's rows on the ramp (_receiver_rows)
            n_on = len(on) if on is not None else int(np.count_nonzero(s["on_ramp"]))
            cell_speed, eta = np.empty(len(self.cells)), np.empty(n_on)  # the message's
        x, v, out_pair, out_slot, v_cross = self._scratch(len(pairs) + n)  # read before the next call
        out_row, out_act, out_v = self._out
        k = gap_tick(t, self._wave_cfg, self.cells, s["front"], s["speed"], s["length"], noise[:n], x_noise, noise[n:],
                     s["on_ramp"], s["ramp"], s["connected"], s["pos"], send, rows, self._nodes, u, self._rsu_pos,
                     ch._attached, self._latest_row, self._msg_t, self._msg_cells, self._pend_node, self._pend_t,
                     self._pend_msg, self._cnt, out_row, out_act, out_v, self._plan_cfg, pairs, t_slot, has_slot, x, v,
                     out_pair, out_slot, self._near_cells, cell_speed, eta, v_cross, self._n_plan)
        if send:
            msg = self._plan_message(t, s, len(pairs), int(self._n_plan[0]), cell_speed, eta)
            if m:
                self._msg_objs.append(msg)  # its row: the send order
        return k

    def _plan_message(self, t: float, s: dict[str, Any], m: int, n_out: int, cell_speed: np.ndarray, eta: np.ndarray
                      ) -> MergePlan:
        """The RSU's message from ``measure_plan``'s output (``m`` pairs before it, ``n_out`` rows out; the work
        arrays ``_scratch``'s): the pairs, slots and events kept, the partners named."""
        _, _, out_pair, out_slot, v_cross = self._scratch(0)
        yielder = self._pick_yielder(t, s, False)  # WaveDamping._measure's (no courtesy stop: None)
        slots = self._slots_from(t, s["ids"], s["connected"], m, out_pair[:n_out], out_slot[:n_out])
        row, connected = self._rows(s), s["connected"]
        partners = {c: r for r, c in self.pairs.items() if r in slots and connected[row[c]]}
        leaders = {c: r for r, c in self.leaders.items()}
        self._partnered.update(partners)
        self._partnered.update(leaders)
        return MergePlan(t, self.cells, cell_speed, eta, yielder, slots, partners, float(v_cross[0]), leaders)

    def _scratch(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``measure_plan``'s work arrays (noisy x, v; pairs and slots out; the crossing speed) for ``n`` rows,
        kept from call to call (grown by doubling)."""
        w = self._work
        if w is None or len(w[0]) < n:
            k = max(n, 64) if w is None else max(n, 2 * len(w[0]))
            w = self._work = (np.empty(k), np.empty(k), np.empty((k, 4), dtype=np.int64), np.empty((k, 11)), np.empty(1))
        return w

    def _pair_arrays(self, s: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pairs as rows (ramp vehicle, partner; -1: gone), their slots so far and whether they have one."""
        if not self.pairs:
            return self._no_pairs
        row, m = self._rows(s), len(self.pairs)
        pairs = np.empty((m, 2), dtype=np.int64)
        t_slot, has_slot = np.zeros(m), np.zeros(m, dtype=bool)
        for q, (r, c) in enumerate(self.pairs.items()):
            pairs[q, 0], pairs[q, 1] = row.get(r, -1), row.get(c, -1)
            ts = self._t_slot.get(r)
            if ts is not None:
                t_slot[q], has_slot[q] = ts, True
        return pairs, t_slot, has_slot

    def _slots_from(self, t: float, ids: list[str], connected: np.ndarray, m: int, out_pair: np.ndarray,
                    out_slot: np.ndarray, held: np.ndarray | None = None) -> dict[str, Slot]:
        """The pairs, slots, connected leaders, held slots (``held``: per row; None: none) and events from
        ``plan_slots``' output (``m`` pairs before it)."""
        rows, vals = out_pair.tolist(), out_slot.tolist()
        for kr, kc, _, _ in (rows[m:] if len(rows) > m else ()):  # the new pairs (few steps), in pairing order
            self.events.emit(t, self.name, "gap_pair", f"{ids[kc]} opens a gap for {ids[kr]}", vehicle=ids[kr])
        self.pairs, self._t_slot, self.leaders = pairs, t_slot, leaders = {}, {}, {}
        lead_on = self.gp.lead_close_up
        held_l = held.tolist() if held is not None else [False] * len(rows)
        self._held = set()
        out: dict[str, Slot] = {}
        for (kr, kc, status, j), f, h in zip(rows, vals, held_l, strict=True):
            if status != ST_SLOT:
                continue
            r = ids[kr]
            pairs[r], t_slot[r] = ids[kc], f[0]
            if h:
                self._held.add(r)
            if lead_on and j >= 0 and connected[j]:
                leaders[r] = ids[j]
            out[r] = Slot(f[0], f[1], (f[2], f[3], f[4]) if j >= 0 else None, (f[5], f[6], f[7]), (f[8], f[9], f[10]))
        return out

    def _rows(self, s: dict[str, Any]) -> dict[str, int]:
        """Vehicle -> row of this tick's state (once per tick)."""
        row = s.get("_row")
        if row is None:
            row = s["_row"] = dict(zip(s["ids"], range(len(s["ids"]))))
        return row  # type: ignore[no-any-return]

    def _slots_py(self, t: float, s: dict[str, Any], v_cross: float) -> dict[str, Slot]:
        """The reference of ``_slots`` (``gap_kernel.plan_slots`` computes the same).  Pair the connected
        ramp vehicles, then per pair: the ramp vehicle's arrival at the junction,
        ``ramp_time_gap_s`` after the predicted arrival of the highway vehicle just ahead of its partner
        (and no earlier than it can make it), its partner's ``open_time_gap_s`` later (RSU sensing: noisy)."""
        p = self.gp
        x = self._projected(s) + self.pos_rng.normal(0.0, p.ramp_sensor_noise_m, len(s["front"]))
        v = np.maximum(s["speed"] + self.sensor_rng.normal(0.0, self.p.sensor_noise_mps, len(s["speed"])), 0.0)
        eta = t + np.maximum(self.merge_x - x, 0.0) / np.maximum(v, 1.0)  # [s] at today's speed
        # [s] the earliest arrival of the connected ramp vehicles (the only ones read; the others nan),
        # on Python floats: the same bits
        earliest = np.full(len(x), np.nan)
        for k in np.flatnonzero(s["connected"] & s["ramp"]).tolist():
            earliest[k] = t + time_to_go(max(self.merge_x - float(x[k]), 0.0), float(v[k]), v_cross, p.plan_accel_mps2)
        dist = np.maximum(self.merge_x - x, 0.0)
        self._v_cross = v_cross
        self._pair_py(t, s, eta, earliest, dist, v)
        row = {vid: k for k, vid in enumerate(s["ids"])}
        self.leaders = {}
        state = lambda j: (float(x[j]), float(v[j]), float(s["length"][j]))  # noqa: E731
        out: dict[str, Slot] = {}
        for r, c in self.pairs.items():
            kr, kc = row[r], row[c]
            # the slot holds once given (a ramp vehicle that follows its plan keeps its earliest arrival
            # at the slot; re-planning from it each time let the slot, and the partner, drift later)
            t_slot = self._t_slot.get(r, float(earliest[kr]))
            running = (v[kr] >= p.min_run_speed_mps  # on its run to the junction: the pair is kept
                       and dist[kr] <= v[kr] ** 2 / (2.0 * p.b_comfort_mps2) + p.commit_m)
            if earliest[kr] > t_slot + p.ramp_time_gap_s and not running:  # it cannot make it: free again
                self._dropped.add(r)
                continue
            j = self._lead_of(s, kc)
            lead = None
            held = r in self._held  # lead_hold: neither moved with the leader's re-plan nor re-checked
            if j is not None:
                lead = state(j)
                if not held:
                    t_slot = max(t_slot, self._lead_term(s, j, t, eta, dist, v))
            h2 = self._follow_gap(float(v[kr]), float(dist[kr]))
            if not running and not held and not self._fits(s, kc, t, t_slot, eta, x, h2):
                self._dropped.add(r)  # the follower would arrive too early (a partner: slow too much)
                continue
            if j is not None and p.lead_close_up and s["connected"][j]:
                self.leaders[r] = s["ids"][j]
            self._t_slot[r] = t_slot
            out[r] = Slot(t_slot, t_slot + h2, lead, state(kc), state(kr))
        for r in self._dropped:
            self.pairs.pop(r, None)
            self._t_slot.pop(r, None)
        self._dropped.clear()
        self._held.intersection_update(self.pairs)
        self._t_slot = {r: v for r, v in self._t_slot.items() if r in self.pairs}
        return out

    def _pair_py(self, t: float, s: dict[str, Any], eta: np.ndarray, earliest: np.ndarray, dist: np.ndarray,
                 v: np.ndarray) -> None:
        """Keep the pairs whose ramp vehicle has not crossed and whose partner has not reached the
        junction; give every other connected ramp vehicle (in their order on the ramp) the first
        connected highway vehicle that can arrive ``open_time_gap_s`` after it without slowing below
        ``partner_min_speed_mps`` (the ramp vehicle arriving ``ramp_time_gap_s`` after the highway
        vehicle ahead of that partner, and no earlier than it can).  With ``lead_close_up`` first a follower,
        human or connected, behind a connected leader that leaves the gap at its own speed (the leader closing
        up: ``_lead_term``), then, none found, the partner-slows pairing."""
        ids, front = s["ids"], s["front"]
        row = {vid: k for k, vid in enumerate(ids)}
        self.pairs = {r: c for r, c in self.pairs.items() if r in row and c in row
                      and front[row[r]] < self.cross_x and front[row[c]] < self.merge_x}
        self._held.intersection_update(self.pairs)  # a ramp vehicle paired again is held only if so paired
        taken = set(self.pairs.values())
        ramp = [k for k in np.flatnonzero(s["connected"] & s["ramp"] & s["on_ramp"]).tolist() if ids[k] not in self.pairs]
        if self.gp.pair_queue_head_only:  # none behind an unconnected vehicle on the ramp (it waits for that one)
            humans = front[s["on_ramp"] & ~s["connected"]].tolist()
            ramp = [k for k in ramp if not any(h > float(front[k]) for h in humans)]
        # followers: connected highway vehicles (partners, they open the gap) and, with a natural gap
        # ahead of them, human ones
        hw = np.flatnonzero(~s["ramp"] & ~s["on_ramp"] & (front < self.merge_x - 10.0)
                            & (front > self.merge_x - self.gp.pair_zone_m))
        p = self.gp
        t_prev = max([self._t_slot.get(r, -math.inf) for r in self.pairs], default=-math.inf)
        if not ramp:
            return
        # Python floats from here (the same values, without numpy's per-element cost)
        eta_l, earliest_l, dist_l, front_l = eta.tolist(), earliest.tolist(), dist.tolist(), front.tolist()
        speed_l, conn_l, hw_l, v_l = s["speed"].tolist(), s["connected"].tolist(), hw.tolist(), v.tolist()
        for k in sorted(ramp, key=lambda j: dist_l[j]):  # in their order on the ramp
            best = None
            h2 = self._follow_gap(speed_l[k], dist_l[k])
            cands = sorted((j for j in hw_l if ids[j] not in taken), key=lambda i: eta_l[i])
            held = False
            if p.lead_close_up and h2 <= (p.restart_gap_s - 1e-9 if self._hold else p.open_time_gap_s):
                for j in cands:  # behind a connected leader, nobody slowing
                    lead = self._lead_of(s, j)
                    if lead is None or not conn_l[lead]:
                        continue
                    t_ramp = max(earliest_l[k], t_prev + p.open_time_gap_s,
                                 self._lead_term(s, lead, t, eta_l, dist_l, v_l))
                    if eta_l[j] >= t_ramp + h2 + p.human_margin_s + self._noise_margin(j, lead, dist_l, v_l):
                        best, held = (j, t_ramp), self._hold
                        break
            if self._hold and best is None:  # no partner slows: a natural gap, any follower at its own speed
                for j in cands:
                    lead = self._lead_of(s, j)
                    t_ramp = max(earliest_l[k], t_prev + p.open_time_gap_s,
                                 self._lead_term(s, lead, t, eta_l, dist_l, v_l) if lead is not None else -math.inf)
                    if (h2 < p.restart_gap_s - 1e-9 and eta_l[j] >= t_ramp + h2 + p.human_margin_s
                            + self._noise_margin(j, lead, dist_l, v_l)):
                        best = (j, t_ramp)
                        break
            for j in cands if best is None and not self._hold else ():
                lead = self._lead_of(s, j)
                t_ramp = max(earliest_l[k], t_prev + p.open_time_gap_s,
                             self._lead_term(s, lead, t, eta_l, dist_l, v_l) if lead is not None else -math.inf)
                if self._fits_at(conn_l[j], front_l[j], eta_l[j], t, t_ramp, h2):
                    best = (j, t_ramp)
                    break
            if best is None:
                continue
            j, t_ramp = best
            self.pairs[ids[k]] = ids[j]
            self._t_slot[ids[k]] = float(t_ramp)
            if held:
                self._held.add(ids[k])
            taken.add(ids[j])
            t_prev = t_ramp
            self.events.emit(t, self.name, "gap_pair", f"{ids[j]} opens a gap for {ids[k]}", vehicle=ids[k])

    def _lead_term(self, s: dict[str, Any], j: int, t: float, eta: Any, dist: Any, v: Any) -> float:
        """[s] the earliest slot behind highway vehicle ``j`` (RSU's view: arrival ``eta``, distance ``dist``,
        speed ``v``, indexable by row): ``ramp_time_gap_s`` after its arrival; with ``lead_close_up`` and ``j``
        connected ``lead_ramp_gap_s`` after its planned arrival, which closing up advances: no later than today's,
        no earlier than ``lead_time_gap_s`` after its own leader's, nor than it can make it accelerating at
        ``a_max_mps2`` to ``u_max_mps`` (the limit)."""
        p = self.gp
        if not (p.lead_close_up and s["connected"][j]):
            return float(eta[j]) + p.ramp_time_gap_s
        t_plan = t + time_to_go(float(dist[j]), float(v[j]), p.u_max_mps, p.a_max_mps2)
        j2 = self._lead_of(s, j)
        if j2 is not None:
            t_plan = max(t_plan, float(eta[j2]) + p.lead_time_gap_s)
        return min(float(eta[j]), t_plan) + p.lead_ramp_gap_s

    def _follow_gap(self, v_mps: float, dist_m: float) -> float:
        """[s] between the ramp vehicle's arrival and its follower's: ``restart_gap_s`` for one that
        stands near the stop line (it starts from rest: the follower must be able to stop behind it);
        with ``lead_hold`` the calibrated humans' desired gap front to front at the crossing speed."""
        p = self.gp
        if v_mps < p.min_run_speed_mps and dist_m <= p.commit_m:
            return p.restart_gap_s
        if self._hold:
            return p.lead_follow_tau_s + p.lead_follow_gap_m / max(self._v_cross, MIN_CROSS_SPEED_MPS)
        return p.open_time_gap_s

    @property
    def _hold(self) -> bool:
        """The gap made from ahead's second iteration is on (``lead_hold`` with ``lead_close_up``)."""
        return self.gp.lead_close_up and self.gp.lead_hold

    def _noise_margin(self, j: int, lead: int | None, dist: Any, v: Any) -> float:
        """[s] ``lead_noise_k`` standard deviations of the difference of the RSU's predicted arrivals (distance /
        speed, each with its position noise ``ramp_sensor_noise_m`` and speed noise ``sensor_noise_mps``) of
        follower ``j`` and of ``lead`` (None: the follower's alone); 0 without ``lead_hold``.  To first order
        var(d / v) = (σ_x / v)² + (d σ_v / v²)²."""
        if not self._hold:
            return 0.0
        sx, sv = self.gp.ramp_sensor_noise_m, self.p.sensor_noise_mps
        var = 0.0
        for k in (j,) if lead is None else (j, lead):
            vk = max(float(v[k]), 1.0)
            var += (sx / vk) ** 2 + (float(dist[k]) * sv / (vk * vk)) ** 2
        return self.gp.lead_noise_k * math.sqrt(var)

    def _closing(self, s: dict[str, Any]) -> list[str]:
        """``lead_hold``: the connected highway vehicles in the pair zone, when a connected ramp vehicle is on the
        ramp before the junction's end (none: [])."""
        front = s["front"]
        if not np.any(s["connected"] & s["on_ramp"] & (front < self.cross_x)):
            return []
        hw = np.flatnonzero(s["connected"] & ~s["ramp"] & ~s["on_ramp"] & (front < self.merge_x)
                            & (front > self.merge_x - self.gp.pair_zone_m))
        return [s["ids"][k] for k in hw.tolist()]

    def _fits(self, s: dict[str, Any], j: int, t: float, t_ramp: float, eta: np.ndarray, x: np.ndarray,
              h2: float) -> bool:
        """Highway vehicle ``j`` can follow a ramp vehicle that reaches the junction at ``t_ramp`` [s]:
        a connected one (a partner) without slowing below ``partner_min_speed_mps``, a human one at
        today's speed with ``human_margin_s`` to spare."""
        return self._fits_at(bool(s["connected"][j]), float(x[j]), float(eta[j]), t, t_ramp, h2)

    def _fits_at(self, connected: bool, x_j: float, eta_j: float, t: float, t_ramp: float, h2: float) -> bool:
        """``_fits`` for a highway vehicle at ``x_j`` [m] predicted at the junction at ``eta_j`` [s]."""
        p = self.gp
        if connected and not self._hold:  # lead_hold: no partner slows, it follows at its own speed
            v_min = p.partner_min_speed_mps if h2 <= p.open_time_gap_s else p.restart_partner_speed_mps
            return t + (self.merge_x - x_j) / v_min >= t_ramp + h2
        return h2 <= p.open_time_gap_s and eta_j >= t_ramp + h2 + p.human_margin_s  # no restart behind a human

    def _lead_of(self, s: dict[str, Any], j: int) -> int | None:
        """The highway vehicle just ahead of vehicle ``j`` on the highway line (None: none)."""
        leads = s.get("_lead")
        if leads is None:  # once per tick, for every vehicle: the highway line's vehicles by front (ties
            # by index: argmin's pick), and in that order the first whose front is > front[j] + 0.1
            line = np.flatnonzero(~s["on_ramp"] & ~s["ramp"])
            order = line[np.argsort(s["front"][line], kind="stable")]
            i = np.searchsorted(s["front"][order], s["front"] + 0.1, side="right")
            leads = s["_lead"] = [None if k >= len(order) else int(order[k]) for k in i.tolist()]
        return leads[j]  # type: ignore[no-any-return]

    # ------------------------------------------------------------------ decide
    def _decide(self, t: float, s: dict[str, Any]) -> list[Any]:
        cmds = super()._decide(t, s)
        self._decide_more(t, s, cmds)
        return cmds

    def _decide_more(self, t: float, s: dict[str, Any], cmds: list[Any]) -> None:
        """The connected ramp vehicles' commands."""
        rows = s.get("_cramp")  # this tick's (_receiver_rows) or found here
        if rows is None:
            rows = np.flatnonzero(s["connected"] & s["ramp"]).tolist()
        if not rows:
            return
        ids, front, on_ramp = s["ids"], s["front"].tolist(), s["on_ramp"].tolist()
        speed = s["speed"].tolist()  # Python floats: the same values
        leaders = self._ramp_leaders(s, front, speed)
        merge_x, cos_ramp = self.merge_x, self.cos_ramp
        command = self._ramp_command_c if self.compiled and HAVE_C_POW else self._ramp_command
        # fronts of the unconnected vehicles on the ramp (pair_queue_head_only): a connected vehicle behind
        # one of them, without a slot, is left to its driver, who queues behind it up to the yield line;
        # the wait law would stop it where its run-up fits and hold the ramp queue behind it there
        # (the last of them: behind any one of them is behind it)
        human_x = (float(s["front"][s["on_ramp"] & ~s["connected"]].max(initial=-math.inf))
                   if self.gp.pair_queue_head_only else -math.inf)
        for k in rows:
            vid = ids[k]
            if front[k] >= self.cross_x or not (on_ramp[k] or vid in self.committed):
                self.committed.discard(vid)
                self._release(vid, cmds)  # joined the highway (or entered the junction on its own)
                continue
            msg = self._latest_of(vid)
            if not isinstance(msg, MergePlan) or t - msg.t_sent_s > self.p.stale_after_s:
                if vid in self.controlled:
                    self.fallbacks += 1
                self.committed.discard(vid)
                self._release(vid, cmds)
                continue
            if front[k] < human_x and vid not in self.committed and vid not in msg.slots:
                self._release(vid, cmds)
                continue
            x = merge_x - (merge_x - front[k]) / cos_ramp if on_ramp[k] else front[k]  # _projected's value
            v_cmd, mode = command(t, msg, vid, x, speed[k], leaders(k))
            cmds.append(SetSpeed(vid, v_cmd, mode))
            self.controlled.add(vid)
            self.commands_sent += 1

    def _ramp_command(self, t: float, msg: MergePlan, vid: str, x: float, v: float, leader: tuple[float, float]
                      ) -> tuple[float, int]:
        """Speed and speed mode of connected ramp vehicle ``vid`` (projected ``x`` [m], speed ``v`` [m/s],
        its physical leader's gap [m] and speed [m/s]): its arrival plan, the safety layer against its
        virtual leader and its physical leader; a reserved crossing once the go / no-go holds."""
        p = self.gp
        dist = max(self.merge_x - x, 0.0)  # [m] to the junction along the ramp
        slot = msg.slots.get(vid)
        age = t - msg.t_sent_s
        if vid in self.committed:  # crossing: on at the crossing speed (the safety layer still bounds it)
            a = K_SPEED * (msg.cross_speed_mps - v)
        elif slot is None:  # wait for a partner where the run-up to the crossing speed still fits
            run_up = msg.cross_speed_mps ** 2 / (2.0 * p.plan_accel_mps2) + p.commit_m
            room = max(dist - run_up, 0.0)
            a = K_SPEED * (min(p.wait_speed_mps, math.sqrt(2.0 * p.b_comfort_mps2 * room)) - v)
        else:
            a = arrival_accel(dist, v, slot.t_ramp_s - t, msg.cross_speed_mps, p.plan_accel_mps2, p.b_comfort_mps2)
        a = float(min(max(a, -p.b_comfort_mps2), p.a_max_mps2))  # np.clip's value, without its call
        lead_ok = True
        if slot is not None and slot.lead is not None:
            x_l, v_l, len_l = slot.lead
            gap = x_l + v_l * age - len_l - x
            if gap > 0.0:  # projected ahead: keep a safe gap behind it (behind: the slot waits for it)
                a = safe_accel(gap, v, v_l, a, self.safety)
            lead_ok = gap > 0.0 and a > -p.b_comfort_mps2
        gap, v_lead = leader
        if math.isfinite(gap):
            a = safe_accel(gap, v, v_lead, a, self.safety)
        v_next = max(0.0, v + a * self.period)
        if vid not in self.committed and slot is not None and lead_ok and self._partner_ok(slot, age, x, v):
            if dist <= v * v / (2.0 * p.b_comfort_mps2) + p.commit_m:
                self.committed.add(vid)
                self.reserved_crossings += 1
                self.events.emit(t, self.name, "reserved_crossing", f"{vid}: crosses on its reservation", vehicle=vid)
        if vid in self.committed and not lead_ok:  # the gap closed: back to the yield sign
            self.committed.discard(vid)
        return v_next, (p.reserved_speed_mode if vid in self.committed else self.p.command_speed_mode)

    def _ramp_command_c(self, t: float, msg: MergePlan, vid: str, x: float, v: float, leader: tuple[float, float]
                        ) -> tuple[float, int]:
        """``_ramp_command`` with its values from one compiled call (``gap_kernel.ramp_command``); the
        committed set, the counter and the event here, as there."""
        slot = msg.slots.get(vid)
        committed = vid in self.committed
        gap, v_lead = leader
        if slot is None:
            v_next, commit, lead_ok = ramp_command(self._ramp_cfg, t, msg.t_sent_s, msg.cross_speed_mps, committed,
                                                   False, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, x, v, gap, v_lead)
        else:
            lead, partner = slot.lead, slot.partner
            has_lead = lead is not None
            lx, lv, ll = lead if lead is not None else (0.0, 0.0, 0.0)
            v_next, commit, lead_ok = ramp_command(self._ramp_cfg, t, msg.t_sent_s, msg.cross_speed_mps, committed,
                                                   True, slot.t_ramp_s, has_lead, lx, lv, ll, partner[0], partner[1],
                                                   slot.ramp[2], x, v, gap, v_lead)
        if commit:
            self.committed.add(vid)
            self.reserved_crossings += 1
            self.events.emit(t, self.name, "reserved_crossing", f"{vid}: crosses on its reservation", vehicle=vid)
            committed = True
        if committed and not lead_ok:  # the gap closed: back to the yield sign
            self.committed.discard(vid)
            committed = False
        return v_next, (self.gp.reserved_speed_mode if committed else self.p.command_speed_mode)

    def _partner_ok(self, slot: Slot, age: float, x_r: float, v_r: float) -> bool:
        """The partner can stay behind the ramp vehicle braking at most comfortably (RSU's measurement)."""
        x_c, v_c, _ = slot.partner
        gap = x_r - slot.ramp[2] - (x_c + v_c * age)
        return gap > 0.0 and safe_accel(gap, v_c, v_r, 0.0, self.safety) > -self.gp.b_comfort_mps2

    def _ramp_leaders(self, s: dict[str, Any], front: list[float], speed: list[float]
                      ) -> Callable[[int], tuple[float, float]]:
        """``_ramp_leader`` for any row of this tick (``front``, ``speed``: the rows' as floats), from one
        stable sort of the vehicles on the ramp by front (ties by row: argmin's pick; finite fronts), the
        first whose front is greater."""
        on = s.get("_onramp")  # this tick's (_receiver_rows) or found here
        order = sorted(np.flatnonzero(s["on_ramp"]).tolist() if on is None else on, key=front.__getitem__)
        keys = [front[j] for j in order]
        length, cos_ramp = s["length"], self.cos_ramp

        def leader(k: int) -> tuple[float, float]:
            i = bisect.bisect_right(keys, front[k] + 1e-6)
            if i == len(order):
                return math.inf, 0.0
            j = order[i]
            return (front[j] - front[k]) / cos_ramp - float(length[j]), speed[j]
        return leader

    def _ramp_leader(self, s: dict[str, Any], k: int) -> tuple[float, float]:
        """The physical leader on the ramp (gap [m], its speed [m/s]); (inf, 0) when none (the reference
        of ``_ramp_leaders``)."""
        on = np.flatnonzero(s["on_ramp"] & (s["front"] > s["front"][k] + 1e-6))
        if not len(on):
            return math.inf, 0.0
        j = int(on[np.argmin(s["front"][on])])
        gap = (s["front"][j] - s["front"][k]) / self.cos_ramp - s["length"][j]
        return float(gap), float(s["speed"][j])

    def _speed(self, t: float, msg: RoadAhead, x: float, v: float, gap: float, v_lead: float, vid: str = "") -> float:
        """The wave-damping speed (a connected leader's: ``_lead_speed``); for a partner capped to reach the
        junction no earlier than its slot and bounded by the safety layer behind the projected ramp vehicle."""
        if isinstance(msg, MergePlan) and vid in msg.leaders:
            v_cmd = self._lead_speed(v, gap, v_lead)
        else:
            v_cmd = super()._speed(t, msg, x, v, gap, v_lead, vid)
        return self._partner_cap(t, msg, x, v, vid, v_cmd)

    def _lead_speed(self, v: float, gap: float, v_lead: float) -> float:
        """[m/s] a connected leader closing up to its own leader (``gap`` [m], ``v_lead`` [m/s]; inf: none):
        the constant-time-gap ACC law of Milanés & Shladover (2014), a = k_gap (gap - s0 - T v) + k_speed
        (v_lead - v) with T = ``lead_time_gap_s``, the change bounded as the wave law's, never above the limit
        (``u_max_mps``), then the safety layer."""
        p = self.gp
        if math.isfinite(gap):
            a = p.lead_k_gap * (gap - self.safety.s0_m - p.lead_time_gap_s * v) + p.lead_k_speed * (v_lead - v)
        else:
            a = p.a_max_mps2
        a = min(max(min(a, (p.u_max_mps - v) / self.period), -p.b_comfort_mps2), p.a_max_mps2)
        if math.isfinite(gap):
            a = safe_accel(gap, v, v_lead, a, self.safety)
        return max(0.0, v + a * self.period)

    def _line_leader(self, s: dict[str, Any], k: int) -> tuple[float, float]:
        """Row ``k``'s physical leader on the highway line as ``WaveDamping._decide`` finds it (the vehicles
        not on the ramp, sorted stably by front, the next one): its gap [m] and speed [m/s]; (inf, u_max)."""
        nxt = s.get("_line_next")
        if nxt is None:  # once per tick
            line = np.flatnonzero(~s["on_ramp"])
            order = line[np.argsort(s["front"][line], kind="stable")].tolist()
            nxt = s["_line_next"] = dict(zip(order, [*order[1:], -1], strict=True))
        j = nxt.get(k, -1)
        if j < 0:
            return math.inf, self.p.u_max_mps
        return float(s["front"][j] - s["length"][j] - s["front"][k]), float(s["speed"][j])

    def _capped(self, t: float, s: dict[str, Any], k: int, vid: str, v_cmd: float) -> float:
        if vid not in self._partnered:  # a partner in no message: its message names it in none (the tick
            return v_cmd  # calls it only for those)
        msg = self._latest_of(vid)
        assert msg is not None  # commanded: a fresh message
        if isinstance(msg, MergePlan) and vid in msg.leaders:  # the connected leader's law, not the wave law's
            v_cmd = self._lead_speed(float(s["speed"][k]), *self._line_leader(s, k))
        if not HAVE_C_POW:
            return self._partner_cap(t, msg, float(s["front"][k]), float(s["speed"][k]), vid, v_cmd)
        if not isinstance(msg, MergePlan) or vid not in msg.partners:
            return v_cmd
        slot = msg.slots[msg.partners[vid]]  # _partner_cap's value in one compiled call
        x_r, v_r, len_r = slot.ramp
        return partner_cap(self._ramp_cfg, t, msg.t_sent_s, slot.t_partner_s, slot.t_ramp_s, x_r, v_r, len_r,
                           float(s["front"][k]), float(s["speed"][k]), v_cmd)

    def _partner_cap(self, t: float, msg: RoadAhead, x: float, v: float, vid: str, v_cmd: float) -> float:
        """``v_cmd`` [m/s] of vehicle ``vid`` at ``x`` [m], ``v`` [m/s] capped for a partner (see ``_speed``)."""
        if not isinstance(msg, MergePlan) or vid not in msg.partners:
            return v_cmd
        slot = msg.slots[msg.partners[vid]]
        age = t - msg.t_sent_s
        v_floor = (self.gp.partner_min_speed_mps if slot.t_partner_s - slot.t_ramp_s <= self.gp.open_time_gap_s
                   else self.gp.restart_partner_speed_mps)
        v_cap = max((self.merge_x - x) / max(slot.t_partner_s - t, 1e-3),  # [m/s] arrive at (or after) the slot
                    min(v_floor, v))
        a = max((v_cap - v) / self.period, -self.gp.b_comfort_mps2)
        x_r, v_r, len_r = slot.ramp
        g = x_r + v_r * age - len_r - x
        if g > 0 and v_r > self.gp.wait_speed_mps:  # a ramp vehicle on its run to the junction
            a = safe_accel(g, v, v_r, a, self.safety)
        return max(0.0, min(v_cmd, v + a * self.period))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {**super().finish(ctx), "v2x_reserved_crossings": self.reserved_crossings}


__all__ = ["RSU", "GapMerging", "MergePlan", "Slot", "arrival_accel"]
