"""V2X-cooperative on-ramp merging in SUMO: a roadside unit (RSU) at the merge assigns crossing
times; connected vehicles follow energy-optimal trajectories to them, under a safety layer.

Per tick (period 0.1 s), in pipeline order:
1. *communicate*: connected vehicles near the merge broadcast CAMs over the lossy, delayed channel;
   the RSU and every controlled vehicle update Kalman tracks (1-D: distance to the merge point)
   from what arrived, all of a tick's messages in one compiled pass (``NodeTrackPool``: filterpy's
   equations, bit for bit); the RSU's sensors see human-driven vehicles with noise.
2. *coordinate*: the RSU gives every vehicle in the control zone a crossing time of the conflict
   point (part-way along the acceleration lane, ``merge_point_frac``) by ``fifo`` or ``cps``
   (constrained position shifting), anchored on the measured crossings, and unicasts (time,
   predecessor) to connected vehicles.
3. *decide*: a connected **ramp** vehicle with a fresh assignment applies, while still on the ramp
   (farther than ``virtual_leader_m`` from the merge point), the closed-form energy-optimal
   acceleration to its assigned crossing time (Rios-Torres & Malikopoulos 2017).  Within
   ``virtual_leader_m`` every vehicle whose predecessor in the crossing order is on the *other*
   road follows that predecessor projected onto its own road ("virtual vehicle" mapping: Uno,
   Sakaguchi & Tsugawa 1999; Lu, Tan & Hedrick 2004): cruise towards the crossing speed, bounded
   by a constant-time-gap rule that opens the gap the lane change needs and by the safe-gap bound
   of the safety layer.  Mainline vehicles behind a mainline predecessor are not commanded: that
   predecessor is their physical leader, and their own driver (SUMO's car-following) follows it.
   A controlled ramp vehicle keeps its own lane-change model and moves over into the opened gap
   when that model accepts it (``hold_lane_change`` holds it until the conflict point instead, which
   costs time with IDM drivers).  With stale information a vehicle
   is handed back to SUMO's car-following model (the vehicle's onboard sensing of its physical
   leader), and the fallback is counted.

   Why the crossing *times* are not tracked near the merge: tracking them made every delay
   self-reinforcing (a late vehicle pushes its followers' slots back, the plans slow them to meet
   the later slots, and they arrive later still); ramp vehicles then crawled to the merge point and
   SUMO moved them over at a median 2.5 m/s, jamming the right lane (41 s mean delay against
   13.6 s for SUMO's own merging, seed 1).  Following the predecessor's actual position keeps the
   order and the gaps without that feedback.

SUMO's safe-speed check (speed mode 31) stays on for commanded vehicles: it is the onboard
collision avoidance w.r.t. the *physical* leader, which a real vehicle senses without V2X.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.addressed_channel import AddressedChannel
from corridor.channel import DELIVERY_TOLERANCE_S, ChannelConfig
from corridor.controllers.merging.cam_kernel import STATUS_OK, CamStage
from corridor.controllers.merging.coord_kernel import (
    F_AOI_MAX,
    F_AOI_SUM,
    HAVE_C_POW,
    I_AOI_N,
    I_DRAW,
    STATUS_DRAWS,
    STATUS_TIE,
    ArrayCoordinator,
    coordinate_into,
    tie_zone,
)
from corridor.controllers.merging.coordinator import Coordinator, CoordinatorConfig, SlotCheck, ZoneVehicle
from corridor.controllers.merging.decide_kernel import (
    G_NAMES,
    I_T_CROSS,
    MODE_CODES,
    OUT_COMMAND_GAP,
    OUT_FALLBACK,
    OUT_LEAVE,
    OUT_PYTHON,
    OUT_RELEASE,
    OUT_SKIP,
    OUT_STALE,
    decide_config,
    decide_into,
)
from corridor.controllers.merging.safety_layer import (
    SafetyParams,
    lane_leaders,
    safe_accel,
    worst_case_leader,
)
from corridor.controllers.merging.switching import (
    DIST_BOUNDARIES,
    MergeBoundaries,
    MergeState,
    QuietMerge,
    VirtualGap,
    clone_automaton,
    merge_automaton,
    resolved,
)
from corridor.controllers.merging.tick_kernel import FUSED_TICK, NOT_RUN
from corridor.controllers.merging.trajectory import MotionLimits, merge_accel, time_to_go
from corridor.engine import Controller, Metric, RunContext
from corridor.modes import HybridAutomaton, SwitchingParams
from corridor.poses import PlanarPoses
from corridor.snapshot import RoadTables, Role
from corridor.traffic.networks.landmarks import OnrampLandmarks
from corridor.traffic.sumo.commands import Release, SetLaneChangeMode, SetSpeed
from corridor.traffic.sumo.road_spec import require_landmarks, road_spec
from corridor.traffic.sumo.trips import road_frame
from corridor.vehicles.tracks.node_pool import NodeTrackPool

RSU = "rsu"
_RAMP = int(Role.RAMP)  # a plain int: numpy compares an IntEnum member several times slower
HOLD_LANE_MODE = 512  # SUMO lane-change mode: no own lane changes (strategic, cooperative, speed gain,
#   keep right all off); TraCI-requested changes respect the others' gaps


_ROADS = ("main", "ramp")  # by an on-the-ramp flag
_ROAD_CODE = {"main": 0, "ramp": 1}  # decide_kernel's predecessor roads (2: another, -1: no predecessor)
# the decision steps a tool may wrap on the instance (tools/trace_hard_brakes): then every decision in Python
_PY_HOOKS = ("_automaton", "_virtual_gap", "_pre_opening_accel", "_gap_opening_accel", "_physical_leader_cap")
# the tick's sends (cam_kernel.CamStage): the count of CAMs and of their receivers, then the sends' sender
# nodes, positions (e, 3) [m], contents (e, 2), ptr (e + 1) into the receiver nodes, those receivers and the
# references: the CAMs first, then room for the RSU's assignments
_Cams = tuple[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True, slots=True)
class Assignment:
    """RSU -> vehicle: cross the merge point at ``t_cross_s`` behind ``pred`` (None: first)."""

    t_sent_s: float
    t_cross_s: float
    pred: str | None
    pred_road: str | None
    cross_ahead: str | None = None  # the nearest vehicle of the other road ahead of ``pred`` in the order,
    #   within the receiver's listening depth, when ``pred`` is on the receiver's road (boundary open_ahead)


class V2XMerging(Controller):
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('v2x_delivery_ratio', '1',
               'Share of the V2X messages sent that were delivered.'),
        Metric('v2x_aoi_mean_s', 's',
               'Mean age of information of the vehicle states the coordinator used.'),
        Metric('v2x_aoi_max_s', 's',
               'Largest age of information of a vehicle state the coordinator used.'),
        Metric('v2x_sent', '1',
               'V2X messages sent.'),
        Metric('v2x_fallbacks', '1',
               "Slots released because a vehicle's state went stale (the vehicle falls back to SUMO's model)."),
        Metric('v2x_dropped_after_end', '1',
               'Messages still in flight when the run ended.'),
        Metric('v2x_dropped_overflow', '1',
               'Messages dropped by a full channel queue.'),
        Metric('v2x_commands', '1',
               'Speed commands the coordinator sent.'),
        Metric('min_virtual_gap_m', 'm',
               'Smallest gap between a ramp vehicle and its virtual (projected) mainline leader.'),
    )
    period = 0.1  # [s] a constant (period_source None), unless the scenario gives `period:`
    compiled_decisions: ClassVar[bool] = True  # the quiet vehicles' decisions in one compiled call (see _decide)
    clone_automata: ClassVar[bool] = True  # new automata cloned from a template per road (switching.clone_automaton)

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        policy: Literal["fifo", "cps"] = "cps"
        channel: str = "v2x"  # a key of the scenario's `channels` (defaults if absent)
        coordinator: CoordinatorConfig = Field(default_factory=CoordinatorConfig)
        limits: MotionLimits = Field(default_factory=lambda: MotionLimits(v_min_mps=2.0, v_max_mps=30.0,
                                                                          a_min_mps2=-3.0, a_max_mps2=2.0))
        safety: SafetyParams = Field(default_factory=SafetyParams)
        stale_after_s: float = Field(1.0, gt=0)  # [s] older information counts as lost: ETSI EN 302
        #   637-2 lets CAMs be up to 1 s apart; a shorter limit makes a lossy channel switch vehicles
        #   between the plan and SUMO's driver every few ticks (30 % loss: 2x the delay at 0.6 s)
        send_margin_m: float = Field(100.0, ge=0)  # [m] CAMs are sent this far before the zone
        release_after_m: float = Field(20.0, ge=0)  # [m] past the merge point a vehicle stops listening
        sensor_noise_m: float = Field(1.0, ge=0)  # [m] RSU sensor noise on human-driven vehicles
        sensor_noise_mps: float = Field(0.5, ge=0)  # [m/s]
        track_process_noise: float = Field(1.0, gt=0)  # [m/s^2] white acceleration density
        virtual_leader_m: float = Field(100.0, gt=0)  # [m] safe gap to the other road's predecessor
        #   (projected on the merge point) is enforced within this distance of the merge
        merge_time_gap_s: float = Field(1.0, ge=0)  # [s] bumper-to-bumper time gap kept to the
        merge_gap_s0_m: float = Field(2.5, ge=0)  # [m]   virtual leader, plus this standstill gap
        merge_point_frac: float = Field(0.1, ge=0, le=1)  # the conflict point, as a share of the
        #   acceleration lane past the nose.  Ramp vehicles reach the stream's speed on the ramp (their
        #   trajectory), so the lane is left for the lane change itself: released half-way (0.5), a
        #   ramp vehicle that found no gap had 100 m left and SUMO braked it hard to the lane end
        #   (seed 8 of the merging batch: 43 such hard brakes, 99 in all against SUMO's own 59; at 0.1: 54)
        target_speed_mps: float | None = None  # crossing speed; None: mainline speed upstream of the zone
        hold_lane_change: bool = False  # True: a controlled ramp vehicle changes lanes only once
        #   released at the conflict point (SetLaneChangeMode, restored by Release).  Off by default:
        #   with IDM drivers the hold made the V2X variants slower than SUMO's own merging (4 seeds:
        #   86-87 s mean delay against 80.6 s, ramp 40 s against 28 s; without it 78.8-79.1 s), and
        #   with Krauss drivers it makes no measurable difference (8 seeds: cps 12.80 / 12.82 s)
        command_speed_mode: int = Field(27, ge=0, le=31)  # SUMO speed mode of commanded vehicles: 27 =
        #   all checks but the type's comfortable decel (bit 2), so a commanded braking is executed up to
        #   the type's emergency decel, as SUMO lets its own drivers brake; 31 caps it at `decel` (with the
        #   calibrated humans, 2 m/s²: commanded ramp vehicles then ran into the ramp's queue)
        comfort_accel_mps2: float = Field(1.0, gt=0)  # [m/s^2] the requested arrival (rank, slot floor)
        #   assumes at most this acceleration towards the crossing speed
        # when a vehicle switches (controllers.merging.switching; defaults: the constants above)
        boundaries: MergeBoundaries = Field(default_factory=MergeBoundaries)
        # stochastic switching near the boundaries (run_scenario --learn --method blrl); default deterministic
        switching: SwitchingParams = Field(default_factory=SwitchingParams)

        @model_validator(mode="before")
        @classmethod
        def _distances_default_to_virtual_leader(cls, data: Any) -> Any:
            """A distance boundary without ``dist_m`` takes ``virtual_leader_m`` (the learner reads numbers)."""
            if not isinstance(data, dict) or not isinstance(data.get("boundaries", {}), dict):
                return data
            d = data.get("virtual_leader_m", 100.0)
            bounds = dict(data.get("boundaries") or {})
            for key in DIST_BOUNDARIES:
                theta = bounds.get(key, {})
                if isinstance(theta, dict) and theta.get("dist_m") is None:
                    bounds[key] = {**theta, "dist_m": d}
            return {**data, "boundaries": bounds}

    @classmethod
    def check_scenario(cls, params: Params, scenario: Any) -> None:
        """At load: the road's network must have an on-ramp (merge point, acceleration lane)."""
        require_landmarks(scenario, OnrampLandmarks, "V2X merging")

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.chan_cfg = scenario.channels.get(params.channel, ChannelConfig())
        # the RSU's coordinator: as arrays in compiled code (coord_kernel), unless a SlotCheck is set or the C
        # library has no powf64 (Python, the same rows)
        check = self._slot_check(params)
        self.coord: Coordinator | ArrayCoordinator = (Coordinator(params.policy, params.coordinator, check)
                                                      if check is not None or not HAVE_C_POW else
                                                      ArrayCoordinator(params.policy, params.coordinator))
        # vehicle id -> key (coord_kernel; the coordinator's id_of is the inverse)
        self._key_of: dict[str, int] = self.coord.key_of if isinstance(self.coord, ArrayCoordinator) else {}
        self._row_key = np.zeros(0, dtype=np.int64)  # per road row: its vehicle key (with _row_node)
        self._entered_of = np.full(64, np.nan)  # per key: the FCFS key (NaN: not in the zone yet), see _coordinate
        self._zbuf = (np.empty((3, 0), dtype=np.int64), np.empty((4, 0)))  # the kernel's zone (_coordinate_compiled)
        if isinstance(self.coord, ArrayCoordinator):  # coordinate_into's packed configuration
            self._coord_cfg = np.array([*self.coord.params_f, params.sensor_noise_m, params.sensor_noise_mps,
                                        params.comfort_accel_mps2])
        self._slot_out = np.empty((0, 4), dtype=np.int64)  # per slot: key, row, connected, on the ramp (coord_kernel)
        self._draws = np.zeros(0)  # the sensor generator's standard normals, taken in batches (coord_kernel)
        self._listen_depth = 1 + (params.coordinator.max_shift if params.policy == "cps" else 0)
        self.assigned: dict[str, tuple[float, Assignment]] = {}  # vid -> (t_recv, assignment)
        self.tracks: NodeTrackPool  # receivers: the controlled vehicles and the RSU (set up in setup)
        self._sent_assignments: dict[int, Assignment] = {}  # in flight, by the reference its copy carries
        self._n_refs = 0
        self._listen_keys = np.zeros(0, dtype=np.int64)  # see _communicate
        self._next_cam = np.zeros(0)  # [s] per channel node: its next CAM (NaN: none yet; CamGenerator.due)
        self._row_node = np.zeros(0, dtype=np.int64)  # per road row: its channel node (-1: none), see _row_nodes
        self._row_node_key: list[str] | None = None
        self._cam = CamStage()  # the compiled CAM stage and its buffers
        self.entered: dict[str, float] = {}
        self.controlled: set[str] = set()
        # the AoI sums: the compiled coordinator's state arrays (coord_kernel), or these
        self._aoi_f, self._aoi_i = ((self.coord.sf, self.coord.si) if isinstance(self.coord, ArrayCoordinator)
                                    else (np.zeros(4), np.zeros(8, dtype=np.int64)))
        self.stale_releases = 0
        self.commands_sent = 0
        self.min_virtual_gap = math.inf
        self.theta = resolved(params.boundaries, params.virtual_leader_m)
        self._quiet = QuietMerge(self.theta)  # quiet_update written out for the merge automata (see _decide)
        self._mode_flags: dict[str, tuple[bool, bool, bool]] = {}  # leaf mode -> what _decide reads of its path
        self.automata: dict[str, HybridAutomaton] = {}  # vid -> its automaton while it holds an assignment
        self._ha_templates: dict[str, HybridAutomaton] = {}  # road -> the automaton new ones are cloned from
        self._dec_code, self._dec_out = np.empty(0, dtype=np.int64), np.empty((0, 4))  # decide_into's outputs
        self._decide_cfg = np.zeros(0)  # decide_into's configuration (setup)
        self._ids_key: tuple[np.ndarray, slice, list[str], dict[str, int]] | None = None  # see _id_rows

    # ------------------------------------------------------------------ wiring
    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        self._ctx = ctx  # per-vehicle switching generators (stochastic switching only)
        lm = self.landmarks = road_frame(ctx).tables.landmarks
        if not hasattr(lm, "joins_mainline"):
            raise ValueError(f"{self.name}: V2X merging needs an on-ramp network (highway_onramp), not {lm.kind!r}")
        # [m] the conflict point: part-way along the acceleration lane, where a ramp vehicle moves over
        # at the stream's speed (at the nose it is still ramp-slow, and a mainline follower would
        # have to brake to a ramp vehicle that is about to accelerate)
        nose, end = float(lm.merge_start_x), float(lm.merge_end_x)
        self.x_merge = nose + self.p.merge_point_frac * (end - nose)
        self.y_rsu = -float(lm.lane_width_m) * float(lm.mainline_lanes)
        self._rsu_pos = np.array([self.x_merge, self.y_rsu, 0.0])  # an assignment's sender position (not read)
        self.cos_ramp = np.cos(np.radians(lm.ramp_angle_deg))
        # per lane code: a ramp lane / the mainline lane that ramp vehicles join / a mainline lane past
        # the nose (a ramp vehicle there has merged) (filled as lanes appear)
        self._on_ramp_lane = np.zeros(0, dtype=bool)
        self._joins_lane = np.zeros(0, dtype=bool)
        self._merged_lane = np.zeros(0, dtype=bool)
        # every message names its receivers: the general channel's addressed sends as node arrays in
        # compiled code (the same draws, copies and statistics, corridor.addressed_channel); the age of
        # information it reports is its own (of the states the coordinator used)
        self.channel = AddressedChannel(self.chan_cfg, ctx.rng(f"{self.name}.channel"), t_end_s=ctx.duration)
        self._send_with_assignments = self.chan_cfg.latency_s > DELIVERY_TOLERANCE_S
        # the CAM stage, the delivery and fuse, and the coordination in one call (tick_kernel), unless the CAMs
        # go out before the delivery (a channel without delay) or the coordinator is Python's
        self._fused = self._send_with_assignments and isinstance(self.coord, ArrayCoordinator)
        self.channel.attach(RSU)
        self._rsu_node = self.channel.node(RSU)
        # the CAM schedule (traffic.v2x.CamGenerator's, per node in cam_kernel): a first CAM at a random phase
        self._cam_period = 1.0 / self.chan_cfg.rate_hz  # [s]
        self._cam_rng = ctx.rng(f"{self.name}.cam")
        zone, p = self.p.coordinator.control_zone_m, self.p
        # [m] senders: near_lo < d < near_hi; listeners: zone_lo < d <= zone_hi (d: to the conflict point)
        #   and the crossing speed's rows (mainline): zone < d < zone + 300 (see _stream_speed)
        self._cam_bounds = (-p.release_after_m - 50, zone + p.send_margin_m, -p.release_after_m, zone, zone, zone + 300.0)
        self.sensor_rng = ctx.rng(f"{self.name}.sensor")
        self.tracks = NodeTrackPool(self.channel.index, process_noise=self.p.track_process_noise, meas_noise=0.5,
                                    vel_noise=0.3, stale_after_s=self.p.stale_after_s)
        self.tracks.add_receiver(RSU)
        self.safety = deliverable_safety(self.p.safety, ctx.scenario, self.p.command_speed_mode, self.period)
        self._decide_cfg = decide_config(self.period, self.p.stale_after_s, self.p.limits, self.p.merge_gap_s0_m,
                                         self.p.merge_time_gap_s, self.safety, self._quiet)

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        state = self._sense(ctx)
        if state is None:
            return
        if self._fused and state.get("poses") is not None:  # the four stages below in one compiled call
            cams, target, (zone, assignments) = self._communicate_and_coordinate(ctx.t, state)
        else:
            cams = self._communicate(ctx.t, state)
            target = self.p.target_speed_mps or self._stream_speed(state)
            zone, assignments = self._coordinate(ctx.t, state, target)
        # the tick's CAMs and the RSU's assignments in one send_many (the same draws, in the same
        # order, as one call each: no copy sent now is due before the next tick, see _communicate)
        if cams is not None:  # (None: sent in the compiled call)
            self._send(ctx.t, cams, assignments)
        ctx.commands.extend(self._decide(ctx.t, state, zone, target))
        self._last_state = state  # the overlays' vehicle positions

    def overlays(self) -> dict[str, tuple[str, Any]]:
        """What a recorder may draw: the ``yield_enter`` and ``merge_enter`` distances as lines across
        the mainline (``merge_enter`` is measured along the ramp; its line marks the same distance to
        the conflict point) and the coordinated vehicles by mode (``modes/<leaf mode>`` points)."""
        out: dict[str, tuple[str, Any]] = {}
        if not hasattr(self, "x_merge"):
            return out
        for key in ("yield_enter", "merge_enter"):
            x = self.x_merge - self.theta[key]["dist_m"]
            out[f"boundaries/{key}"] = ("lines", [np.array([[x, 0.0], [x, self.y_rsu]])])
        st = getattr(self, "_last_state", None)
        if st is not None:
            row = {v: k for k, v in enumerate(st["ids"])}
            pts: dict[str, list[np.ndarray]] = {}
            for vid, ha in self.automata.items():
                if vid in row:
                    pts.setdefault(ha.mode, []).append(st["pos"][row[vid]][:2])
            out.update({f"modes/{m}": ("points", np.array(p)) for m, p in pts.items()})
        return out

    def _sense(self, ctx: RunContext) -> dict[str, Any] | None:
        """Own-vehicle facts each vehicle knows exactly (GNSS/odometry): distance to the merge, road."""
        snap, r = ctx.snapshot, ctx.snapshot.road
        if r is None or len(r) == 0:
            return None
        sl, tb = r.sl, r.tables
        self._classify_lanes(tb)
        ids, row = self._id_rows(snap.ids, sl)
        size = snap.size[sl]
        geo = snap.geometry_source()
        if isinstance(geo, PlanarPoses) and sl == slice(0, len(geo)):
            # SUMO's raw poses: the yaw's cosine and sine as corridor.poses.planar_geometry computes them
            # (numpy's bits), the rows' centres and front x in the compiled CAM stage; the snapshot's own
            # geometry is left to whoever reads it (the monitors derive it in blocks of ticks)
            yaw = np.radians(90.0 - geo.bearing_deg)
            c, sn = np.cos(yaw), np.sin(yaw)
            sp = geo.speed_mps  # the snapshot's speed: the hypot of its velocity (np.hypot's bits: tested)
            return {"ids": ids, "poses": (geo.ref_xy, geo.back_m, c, sn, size), "uid": r.uid, "tables": tb,
                    "speed": np.hypot(sp * c, sp * sn), "accel": r.accel, "lane": r.lane, "length": size[:, 0],
                    "lane_pos": r.lane_pos, "row": row}
        pos, heading = snap.position[sl], snap.heading[sl]
        front_x = pos[:, 0] + 0.5 * size[:, 0] * np.cos(heading)
        # the rest comes with the compiled CAM stage (_communicate; cam_kernel.derive_rows): "dist" (to the
        # conflict point, along the inclined ramp on a ramp lane), "ramp" (on the ramp route), "merged" (a
        # ramp vehicle on a mainline lane past the nose has merged: out of the conflict, like a mainline
        # vehicle that moved to the left lane; its route alone kept it under ramp control), "right" (on the
        # mainline lane ramp vehicles join), "connected"; and "leader" (each row's lane leader,
        # safety_layer.lane_leaders), "stream" and "cand"
        return {"ids": ids, "front_x": front_x, "uid": r.uid, "tables": tb, "speed": snap.speed[sl], "accel": r.accel,
                "pos": pos, "heading": heading, "lane": r.lane, "length": size[:, 0], "lane_pos": r.lane_pos, "row": row}

    def _id_rows(self, ids_arr: np.ndarray, sl: slice) -> tuple[list[str], dict[str, int]]:
        """The road rows' ids and id -> row, rebuilt only when the snapshot's ids array is another
        object: a backend publishes the same (never written) array while its vehicles stay the same,
        about four ticks in five here (read-only for the tick's stages)."""
        key = self._ids_key
        if key is not None and key[0] is ids_arr and key[1] == sl:
            return key[2], key[3]
        ids = ids_arr[sl].tolist()
        row = dict(zip(ids, range(len(ids))))
        self._ids_key = (ids_arr, sl, ids, row)
        return ids, row

    def _classify_lanes(self, tb: RoadTables) -> None:
        """Per lane code, once per lane: on the ramp edge; the mainline lane that ramp vehicles join; a
        mainline lane past the nose."""
        done = len(self._on_ramp_lane)
        if done == tb.n_lanes:
            return
        new = tb.lane_names[done:]
        lm = self.landmarks
        self._on_ramp_lane = np.concatenate([self._on_ramp_lane, [lm.is_ramp_lane(n) for n in new]])
        self._joins_lane = np.concatenate([self._joins_lane, [lm.joins_mainline(n) for n in new]])
        self._merged_lane = np.concatenate([self._merged_lane, [lm.past_nose_mainline(n) for n in new]])

    def _communicate(self, t: float, s: dict[str, Any]) -> _Cams:
        """CAMs out, the copies due now in: returns the tick's CAMs, to be sent with the assignments
        when the channel's delay is never zero (none of them could be delivered in this tick).

        The stage is one compiled call over node indices (``cam_kernel.cam_stage_into``: the zone masks, the
        senders' positions, the CAM schedule, the listen keys, each CAM's receivers); a listener to attach
        or detach, a sender without a node or without a schedule is done here first (``_admit``).

        A CAM is a broadcast; only two kinds of receiver act on it (the RSU, and the vehicles that
        sender may precede in the crossing order), so only those copies are simulated: each is drawn
        with the same per-link range, loss and delay as the broadcast copy would be, at O(N) not
        O(N^2) cost.  A vehicle listens to the few vehicles ahead of it in the current order (one
        more than a re-sequencing can shift), so a new predecessor is already tracked; fifo inserts a
        newcomer by its expected arrival, ahead of vehicles already ordered: they must have heard it
        already (a CAM is a broadcast), so every ordered vehicle also listens to the senders on a
        conflicting lane that are not ordered yet."""
        out = self._cam_stage(t, s)
        if out[0] != STATUS_OK:
            self._admit(t, s)
            out = self._cam_stage(t, s)
            assert out[0] == STATUS_OK, out[0]
        cams = self._took_stage(s, out)
        src, pos, val, ptr, dst, ref = cams[2:]
        n_c, m = cams[0], cams[1]
        if not self._send_with_assignments:  # a copy sent now may be due now: send before delivering
            self._send(t, cams, [])
            cams = (0, 0, src[n_c:], pos[n_c:], val[n_c:], ptr[n_c:] - ptr[n_c], dst[m:], ref[n_c:])
        self._receive(t)
        return cams

    def _communicate_and_coordinate(self, t: float, s: dict[str, Any]
                                    ) -> tuple[_Cams | None, float, tuple[dict[str, int], list[tuple[str, Any, np.ndarray, str]]]]:
        """``_communicate``, the crossing speed, ``_coordinate`` (compiled) and ``_send`` in one compiled call
        (``tick_kernel.fused_tick_into``), with the Python steps around them in the former order: the
        admission (then the call again), the assignments delivered, the coordination's draws and ties (then
        ``_send`` follows in Python). Returns the CAMs to send (None: sent), the target speed [m/s], and the
        zone and assignments."""
        got = self._fused_call(t, s)
        if got is None:
            self._admit(t, s)
            got = self._fused_call(t, s)
            assert got is not None
        r_cam, r_dlv, k, r_crd, target, r_send = got
        # the stage's outputs the tick reads (pose_views' and _took_stage's, without the CAMs' views: the
        # compiled call sent them, unless a step below was left to Python, which takes them then)
        cam, n, n_keys, n_c = self._cam, len(s["ids"]), r_cam[5], r_cam[6]
        s["pos"] = cam.centre[:n]
        s["dist"], s["connected"], s["ramp"], s["right"], s["merged"] = (
            cam.dist[:n], cam.connected[:n], cam.ramp[:n], cam.right[:n], cam.merged[:n])
        self._listen_keys = cam.keys[:n_keys]
        s["stream"], s["cand"], s["leader"] = (r_cam[7], r_cam[8]), cam.cand[:n_c], cam.leader[:n]
        self.tracks.fused_done(self.channel, t, r_dlv)  # _receive's steps after its call
        self._forget_sent(t)
        if k:
            self._take_assignments(k, *self._ref_bufs)
        if r_crd[0] == NOT_RUN:  # the fuse was completed in Python: the coordination on its own
            target = self.p.target_speed_mps or self._stream_speed(s)
            return self._took_stage(s, cam.pose_views(n, r_cam)[:15]), target, self._coordinate(t, s, target)
        zone_out = self._coordinated(t, s, target, *r_crd)
        if r_send[0] == NOT_RUN:  # coordinated in Python (a tie, more draws): _send follows
            return self._took_stage(s, cam.pose_views(n, r_cam)[:15]), target, zone_out
        self.channel.commit_send(*r_send[1:])
        assignments = zone_out[1]
        if assignments:  # their references, as _send keeps them
            sent = self._sent_assignments
            for r, a in enumerate(assignments, start=self._n_refs):
                sent[r] = a[1]
            self._n_refs += len(assignments)
        return None, target, zone_out

    def _fused_call(self, t: float, s: dict[str, Any]) -> tuple[Any, ...] | None:
        """``fused_tick_into`` on the tick (None: the CAM stage's status > 0, nothing done, see ``_admit``)."""
        cam_args = self._cam.pose_args(t, s["poses"], *self._cam_args(t, s))
        ac = self.coord
        assert isinstance(ac, ArrayCoordinator)
        self._coord_room(len(s["ids"]))  # a zone of every row at most
        cam = self._cam
        snd = self.channel.send_buffers(cam.dst.shape[0], cam.src.shape[0])  # the stage's sends at most
        dlv, ref_t, ref_dr = self.tracks.fused_args(self.channel, t)
        self._ref_bufs = (ref_t, ref_dr)
        z_int, z_flt = self._zbuf
        given = self.p.target_speed_mps
        got = FUSED_TICK(*cam_args, *dlv, self._row_key, self.tracks.slot_of_receiver(RSU), self._draws,
                              self._entered_of, ac.s_int, ac.s_flt, ac.si, ac.sf, self._coord_cfg, ac.params_i, z_int,
                              z_flt, self._slot_out, ref_t, ref_dr, given if given else math.nan,
                              self.p.limits.v_max_mps, True, *snd[3:17])
        if got[0][0] != STATUS_OK:  # the rows were derived (for _admit), nothing else done
            n = len(s["ids"])
            s["dist"], s["connected"], s["ramp"], s["right"], s["merged"] = (
                cam.dist[:n], cam.connected[:n], cam.ramp[:n], cam.right[:n], cam.merged[:n])
            return None
        return got

    def _cam_args(self, t: float, s: dict[str, Any]) -> tuple[tuple[Any, ...], ...]:
        """The CAM stage's arguments after the rows' geometry: ``derive_rows``' raw rows, then the rest."""
        index = self.channel.index
        known, chan_pos = self.channel.position_arrays()
        order_node = np.array([index.get(v, -1) for v in self.coord.sequence], dtype=np.int64)
        tb = s["tables"]
        raw = (tb.role, s["uid"], tb.connected, self._on_ramp_lane, self._joins_lane, self._merged_lane, _RAMP,
               self.cos_ramp)
        rest = (s["speed"], self._row_nodes(s), *self._cam_bounds, self.tracks.slot_of, len(self.tracks) - 1,
                self._next_cam, self._cam_period, known, chan_pos, self._rsu_node, self.x_merge, self.y_rsu, order_node,
                self._listen_depth, self.coord.policy == "fifo", self._n_refs, s["lane"], s["lane_pos"])
        return raw, *rest  # type: ignore[return-value]

    def _took_stage(self, s: dict[str, Any], out: tuple[Any, ...]) -> _Cams:
        """The CAM stage's outputs ``out`` into the tick's state; returns the tick's CAMs to send."""
        _, _near, src, pos, val, ptr, dst, keys, stream_sum, stream_n, cand, n_c, m, ref, leader = out
        self._listen_keys = keys
        s["stream"] = (stream_sum, stream_n)  # the crossing speed's sum and count (see _stream_speed)
        s["cand"] = cand  # the rows the RSU coordinates (see _coordinate)
        s["leader"] = leader  # each row's lane leader (see _physical_leader_cap)
        return (n_c, m, src, pos, val, ptr, dst, ref)

    def _cam_stage(self, t: float, s: dict[str, Any]) -> tuple[Any, ...]:
        """``cam_kernel.CamStage`` on the tick's rows (status > 0: nothing done, see ``_admit``)."""
        raw, *rest = self._cam_args(t, s)
        poses = s.get("poses")
        if poses is not None:  # the rows' front x and centres from SUMO's raw poses, in the same call
            out = self._cam.pose_tick(t, poses, raw, *rest)
            s["pos"] = out[20]
        else:
            out = self._cam.tick(t, s["front_x"], raw, s["pos"], *rest)
        s["dist"], s["connected"], s["ramp"], s["right"], s["merged"] = out[15:20]  # (views of the stage's buffers)
        return out[:15]

    def _row_nodes(self, s: dict[str, Any]) -> np.ndarray:
        """Each road row's channel node (-1: none yet), rebuilt when the rows' ids list changes."""
        ids = s["ids"]
        if self._row_node_key is not ids:
            index = self.channel.index
            self._row_node = np.array([index.get(v, -1) for v in ids], dtype=np.int64)
            self._row_node_key = ids
            if isinstance(self.coord, ArrayCoordinator):  # and each row's vehicle key (coord_kernel)
                key_of, id_of = self._key_of, self.coord.id_of
                for v in ids:
                    if v not in key_of:
                        key_of[v] = len(id_of)
                        id_of.append(v)
                self._row_key = np.array([key_of[v] for v in ids], dtype=np.int64)
        return self._row_node

    def _admit(self, t: float, s: dict[str, Any]) -> None:
        """What the compiled stage leaves to names and draws, in the order the Python stage did it:
        attach the vehicles in the zone as listeners (row order) and detach those that left; give every
        sender a node (row order), and a first CAM time at a random phase inside one period (row order:
        ``CamGenerator.due``'s draws)."""
        zone_len = self.p.coordinator.control_zone_m
        ids, dist = s["ids"], s["dist"]
        near = s["connected"] & (dist < zone_len + self.p.send_margin_m) & (dist > -self.p.release_after_m - 50)
        in_zone = s["connected"] & (dist <= zone_len) & (dist > -self.p.release_after_m)
        listening = [ids[k] for k in np.flatnonzero(in_zone).tolist()]
        for vid in listening:  # controlled vehicles listen
            if vid not in self.tracks:
                self.channel.attach(vid)
                self.tracks.add_receiver(vid)
        heard = set(listening)
        for vid in [v for v in self.tracks.receivers if v != RSU and v not in heard]:
            self.channel.detach(vid)
            self.tracks.remove_receiver(vid)
            self.assigned.pop(vid, None)
        sel = [ids[k] for k in np.flatnonzero(near).tolist()]
        nodes = [self.channel.node(v) for v in sel]  # registered on first use, in row order
        if len(self._next_cam) < len(self.channel.names):
            grown = np.full(2 * len(self.channel.names), np.nan)
            grown[: len(self._next_cam)] = self._next_cam
            self._next_cam = grown
        for j in nodes:
            if math.isnan(self._next_cam[j]):
                self._next_cam[j] = t + self._cam_rng.uniform(0.0, self._cam_period)
        if self._row_node_key is ids:  # nodes were registered: only for rows listening or near (see _row_nodes)
            index, rows = self.channel.index, np.flatnonzero(near | in_zone).tolist()
            self._row_node[rows] = [index.get(ids[k], -1) for k in rows]

    def _send(self, t: float, cams: _Cams, assignments: list[tuple[str, Any, np.ndarray, str]]) -> None:
        """The tick's CAMs (multicasts) and then the RSU's assignments (unicasts) in one send: the same
        draws, in the same order, as one send each. An assignment travels as a reference
        (``_sent_assignments``); a CAM as its content [position on the merge axis [m], speed [m/s]]. The
        assignments take the room the CAM stage left after the CAMs (one per connected coordinated row:
        from the RSU's position, the references from ``_n_refs`` on); their receivers are written here."""
        n_c, m, src, pos, val, ptr, dst, ref = cams
        n_a = len(assignments)
        if not n_c and not n_a:
            return
        n = n_c + n_a
        if n_a:
            assert n <= len(src), (n_a, len(src) - n_c)  # an assignment goes to a connected coordinated row
            index, sent = self.channel.index, self._sent_assignments
            for r, a in enumerate(assignments, start=self._n_refs):
                sent[r] = a[1]
            self._n_refs += n_a
            dst[m:m + n_a] = [index.get(a[3], -1) for a in assignments]
        self.channel.send(t, src[:n], pos[:n], ptr[:n + 1], dst[:m + n_a], val[:n], ref[:n])

    def _receive(self, t: float) -> None:
        """The copies due now: fuse the CAMs into the listeners' tracks and forget the stale tracks (with
        the channel's delivery, one compiled call), and keep each vehicle's newest assignment, in the
        channel's delivery order ((t_recv, send order) per pair)."""
        k, t_recv, dst_ref = self.tracks.deliver_fuse_and_drop_refs(self.channel, t, self._rsu_node, self._listen_keys)
        self._forget_sent(t)
        if k:  # the delivered assignments in the order (t_recv, send order), found in the same call
            self._take_assignments(k, t_recv, dst_ref)

    def _take_assignments(self, k: int, t_recv: np.ndarray, dst_ref: np.ndarray) -> None:
        """The ``k`` delivered assignments (arrival times [s], (receiver node, reference)) in delivery order."""
        names, sent, assigned = self.channel.names, self._sent_assignments, self.assigned
        for tr, (dst, ref) in zip(t_recv[:k].tolist(), dst_ref[:k].tolist(), strict=True):
            assigned[names[dst]] = (tr, sent[ref])  # a vehicle keeps the last one delivered

    def _forget_sent(self, t: float) -> None:
        """Forget the assignments whose copies were all delivered or dropped (sent longer ago than the
        channel's largest delay)."""
        sent, horizon = self._sent_assignments, t - self.chan_cfg.latency_s - self.chan_cfg.jitter_s - 1.0
        while sent:
            ref = next(iter(sent))
            if sent[ref].t_sent_s >= horizon:
                break
            del sent[ref]

    def _coordinate(self, t: float, s: dict[str, Any], target: float
                    ) -> tuple[dict[str, int], list[tuple[str, Any, np.ndarray, str]]]:
        """RSU: the zone's vehicles (V2X tracks for connected, noisy sensors for the others) -> times;
        returns the zone (vehicle -> row) and the assignments to send. One compiled call
        (``coord_kernel.coordinate_into``) with the coordinator as arrays; in Python with a ``SlotCheck``
        (``_coordinate_py``, the reference)."""
        if isinstance(self.coord, ArrayCoordinator) and s.get("cand") is not None:
            return self._coordinate_compiled(t, s, target)
        return self._coordinate_py(t, s, target)

    def _coordinate_compiled(self, t: float, s: dict[str, Any], target: float
                             ) -> tuple[dict[str, int], list[tuple[str, Any, np.ndarray, str]]]:
        """``_coordinate_py``'s zone, predictions, sensor readings (the same draws: two standard normals per
        unconnected candidate, in row order), requested arrivals, FCFS keys, crossings, AoI sums and the
        coordinator's assignment in one call; the assignments (one per connected coordinated row) here."""
        self._coord_room(len(s["cand"]))
        args, rest = self._coord_args(t, s, target)
        return self._coordinated(t, s, target, *coordinate_into(*args, self._draws, *rest))

    def _coord_room(self, n_c: int) -> None:
        """Room for a zone of ``n_c`` vehicles: the FCFS keys, the coordinator's slots, the zone, the slots' output."""
        ac = self.coord
        assert isinstance(ac, ArrayCoordinator)
        if len(self._entered_of) < len(ac.id_of):
            grown = np.full(2 * len(ac.id_of), np.nan)
            grown[: len(self._entered_of)] = self._entered_of
            self._entered_of = grown
        ac.room(n_c)
        z_int, z_flt = self._zbuf
        if z_int.shape[1] < n_c:
            m = max(2 * n_c, 16)
            self._zbuf = np.empty((3, m), dtype=np.int64), np.empty((4, m))
        if self._slot_out.shape[0] < ac.s_int.shape[1]:
            self._slot_out = np.empty((ac.s_int.shape[1], 4), dtype=np.int64)

    def _coord_args(self, t: float, s: dict[str, Any], target: float) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
        """``coordinate_into``'s arguments before and after its pool of draws (room made: ``_coord_room``)."""
        ac = self.coord
        assert isinstance(ac, ArrayCoordinator)
        slot, row_of, trk_x, trk_t = self.tracks.receiver_arrays(RSU)
        z_int, z_flt = self._zbuf
        args = (t, s["cand"], s["connected"], s["dist"], s["speed"], s["ramp"], self._row_key, self._row_node, slot,
                row_of, trk_x, trk_t)
        rest = (target, self._entered_of, ac.s_int, ac.s_flt, ac.si, ac.sf, self._coord_cfg, ac.params_i, z_int,
                z_flt, self._slot_out)
        return args, rest

    def _coordinated(self, t: float, s: dict[str, Any], target: float, status: int, nz: int, n: int
                     ) -> tuple[dict[str, int], list[tuple[str, Any, np.ndarray, str]]]:
        """After ``coordinate_into``'s call: more draws (then the call again), the Python coordinator on a tie,
        and the zone and the assignments from the slots."""
        ac = self.coord
        assert isinstance(ac, ArrayCoordinator)
        connected = s["connected"]
        z_int, z_flt = self._zbuf
        if status == STATUS_DRAWS:  # the pool of sensor draws is short: the rest, then new ones (same stream)
            n_c = len(s["cand"])
            args, rest = self._coord_args(t, s, target)
            self._draws = np.concatenate([self._draws[ac.si[I_DRAW]:], self.sensor_rng.standard_normal(max(2 * n_c, 1024))])
            ac.si[I_DRAW] = 0
            status, nz, n = coordinate_into(*args, self._draws, *rest)
        if status == STATUS_TIE:  # the ids break a tie of the FCFS keys: the Python coordinator, same state
            zone = tie_zone(z_int[0], z_int[1], *z_flt, nz, ac.id_of)
            index = dict(zip([zv.id for zv in zone], z_int[2][:nz].tolist(), strict=True))
            dist, row = s["dist"], s["row"]
            crossed = {vid: t for vid in ac.sequence if vid not in index and vid in row and dist[row[vid]] <= 0.0}
            ac.assign_py(t, zone, crossed, self._key_of)
            ramp, n = s["ramp"], len(index)
            self._slot_out[:n] = [(self._key_of[v], k, connected[k], ramp[k]) for v, k in
                                  ((v, index[v]) for v in ac.sequence)]
        if not nz:
            ac.changed()
            return {}, []
        # per slot: its key, row, connected, on the ramp now (a slot keeps the road it was ordered with)
        info, times, ids = self._slot_out[:n].tolist(), ac.s_flt[1, :n].tolist(), ac.id_of
        order = ac.set_sequence([ids[key] for key, _, _, _ in info])
        road_of = dict(zip(order, [_ROADS[r] for _, _, _, r in info], strict=True)) if self._opens_ahead else None
        rsu_pos = self._rsu_pos
        out: list[tuple[str, Any, np.ndarray, str]] = []
        for j, (_, _, conn, _) in enumerate(info):
            if not conn:
                continue
            pred, pred_road = (order[j - 1], _ROADS[info[j - 1][3]]) if j > 0 else (None, None)
            ahead = self._cross_ahead(order, j, road_of) if road_of is not None else None
            out.append((RSU, Assignment(t, times[j], pred, pred_road, ahead), rsu_pos, order[j]))
        rows = [r for _, r, _, _ in info]
        return dict(zip(order, rows, strict=True)), out

    def _coordinate_py(self, t: float, s: dict[str, Any], target: float
                       ) -> tuple[dict[str, int], list[tuple[str, Any, np.ndarray, str]]]:
        """``_coordinate`` in Python on names (the reference; the path with a ``SlotCheck``)."""
        zone_len = self.p.coordinator.control_zone_m
        ids, dist, speed = s["ids"], s["dist"], s["speed"]
        cand_rows = s.get("cand")  # found by the compiled CAM stage (cam_kernel), else:
        if cand_rows is None:
            cand_rows = np.flatnonzero((dist > 0) & (dist <= zone_len) & (s["ramp"] | s["right"]) & ~s["merged"])
        cand = cand_rows.tolist()
        # the RSU's tracks predicted to now in Python floats (TrackPool.predict_one: the bits of
        # predict_states, without its ~15 numpy calls for the few vehicles of the zone)
        predict, connected = self.tracks.predict_one, s["connected"].tolist()
        zone: list[ZoneVehicle] = []
        index: dict[str, int] = {}
        ages: list[float] = []  # [s] of the RSU's tracks of the zone's vehicles (those it tracks: connected)
        for k in cand:
            vid = ids[k]
            if connected[k]:
                est = predict(RSU, vid, t)
                if est is None:
                    continue  # the RSU has not heard from it (yet): not coordinated
                d, v = -est[0], max(est[1], 0.1)
                ages.append(est[2])  # t - its newest CAM's send time (never negative)
            else:
                d = float(dist[k] + self.sensor_rng.normal(0, self.p.sensor_noise_m))
                v = float(max(speed[k] + self.sensor_rng.normal(0, self.p.sensor_noise_mps), 0.1))
            # requested arrival: comfortable acceleration towards the crossing speed (cruise when
            # faster).  From standstill it stays finite, unlike d / v, so a stopped vehicle never
            # gets a slot far away; full-throttle arrival times instead would ask every vehicle to
            # accelerate into its leader, and the misses would reshuffle the schedule each cycle
            earliest = t + time_to_go(max(d, 0.0), v, max(v, target, 1.0), self.p.comfort_accel_mps2)
            if vid not in self.entered:
                # first come, first served *at the merge point*: rank by the arrival time expected
                # at zone entry (ranking by entry time would let slow ramp traffic hold the mainline)
                self.entered[vid] = earliest
            zone.append(ZoneVehicle(vid, "ramp" if s["ramp"][k] else "main", d, v, earliest, self.entered[vid]))
            index[vid] = k
        for age in ages:  # age of information at the RSU, sampled per tick over coordinated vehicles
            self._aoi_sum += age
            self._aoi_n += 1
            self._aoi_max = max(self._aoi_max, age)
        # vehicles of the sequence that reached the merge point since the last call anchor the next
        # headway at their measured crossing time; the others left the conflict (lane change)
        row = s["row"]
        crossed = {vid: t for vid in self.coord.sequence if vid not in index and vid in row and dist[row[vid]] <= 0.0}
        times = self.coord.assign(t, zone, crossed)
        if not zone:
            return {}, []
        order = self.coord.sequence
        road_of = {z.id: z.road for z in zone}
        rsu_pos = np.array([self.x_merge, self.y_rsu, 0.0])
        out: list[tuple[str, Any, np.ndarray, str]] = []
        for pos_, vid in enumerate(order):
            k = index.get(vid)
            if k is None or not s["connected"][k]:
                continue
            pred = order[pos_ - 1] if pos_ > 0 else None
            ahead = self._cross_ahead(order, pos_, road_of) if self._opens_ahead else None
            out.append((RSU, Assignment(t, times[vid], pred, road_of.get(pred) if pred else None, ahead), rsu_pos, vid))
        return index, out

    def _decide(self, t: float, s: dict[str, Any], zone: dict[str, int], target: float) -> list[Any]:
        """Per vehicle holding an assignment: its automaton, then its command (or its release): in one compiled
        call (``decide_kernel.decide_into``) for the vehicles whose automaton stays quiet, in Python
        (``_decide_py``) for the others, and all in Python when a step is wrapped on the instance
        (``tools/trace_hard_brakes``) or ``compiled_decisions`` is off."""
        cmds: list[Any] = []
        dist = s["dist"].item
        live = s["row"]
        controlled, assigned, automata = self.controlled, self.assigned, self.automata
        for vid in list(controlled):  # release vehicles past the merge or gone
            k = live.get(vid)
            if k is None or dist(k) < 0:  # past the nose: SUMO's lane-change model completes the merge
                controlled.discard(vid)
                if k is not None:
                    cmds.append(Release(vid))
        if assigned:
            if self.compiled_decisions and not any(h in self.__dict__ for h in _PY_HOOKS):
                self._decide_compiled(t, s, target, cmds)
            else:
                self._decide_py(t, s, target, list(assigned.items()), cmds)
        if automata:  # past the conflict point, gone, or no longer coordinated
            for vid in [v for v in automata if v not in assigned or live.get(v) is None or dist(live[v]) < 0]:
                del automata[vid]
        return cmds

    def _decide_compiled(self, t: float, s: dict[str, Any], target: float, cmds: list[Any]) -> None:
        """``_decide_py`` on every vehicle holding an assignment, in order: the compiled call first (the quiet
        automata's g values and the commands), the vehicles it leaves to Python (a guard fires, no automaton yet)
        through ``_decide_py`` in their place."""
        live, index, automata, usable = s["row"], self.tracks.index, self.automata, QuietMerge.usable
        items = list(self.assigned.items())
        modes: list[int] = []
        rows = []
        for vid, (_t_recv, a) in items:
            ha = automata.get(vid)
            mode = MODE_CODES.get(ha.mode, -1) if ha is not None and usable(ha) else -1
            modes.append(mode)
            pred, ahead = a.pred, a.cross_ahead
            rows.append((live.get(vid, -1), index.get(vid, -1), mode, index.get(pred, -1), live.get(pred, -1),
                         -1 if pred is None else _ROAD_CODE.get(a.pred_road, 2), index.get(ahead, -1),
                         live.get(ahead, -1), ahead is not None, a.t_sent_s, a.t_cross_s))
        inp = np.array(rows, dtype=np.float64)
        t3 = (inp[:, I_T_CROSS] - t) ** 3  # numpy's, as trajectory.start_accel's (a contiguous array: the same bits)
        n = len(items)
        if self._dec_code.shape[0] < n:
            self._dec_code, self._dec_out = np.empty(2 * n, dtype=np.int64), np.empty((2 * n, 4))
        leader = s.get("leader")
        if leader is None:  # a state without the CAM stage's
            leader = s["leader"] = lane_leaders(s["lane"], s["lane_pos"])
        _, row_of, trk_x, trk_t = self.tracks.receiver_arrays(RSU)
        decide_into(t, target, inp, self._decide_cfg, s["dist"], s["speed"], s["ramp"], s["right"], s["merged"],
                    s["length"], s["lane_pos"], leader, self.tracks.slot_of, row_of, trk_x, trk_t, t3,
                    self._dec_code, self._dec_out)
        codes, out = self._dec_code[:n].tolist(), self._dec_out[:n].tolist()
        controlled, assigned = self.controlled, self.assigned
        hold, mode_cmd = self.p.hold_lane_change, self.p.command_speed_mode
        for (vid, (_t_recv, a)), c, (v_next, g1, g2, gap), mode in zip(items, codes, out, modes, strict=True):
            if c == OUT_SKIP:
                continue
            if c == OUT_LEAVE:
                if vid in controlled:
                    controlled.discard(vid)
                    cmds.append(Release(vid))
                del assigned[vid]
                automata.pop(vid, None)
                continue
            if c == OUT_STALE:
                self._fallback(t, vid, cmds)
                continue
            if c == OUT_PYTHON:
                self._decide_py(t, s, target, [(vid, (_t_recv, a))], cmds)
                continue
            ha = automata[vid]  # QuietMerge's keep: the g values of the mode's boundaries
            names = G_NAMES[mode]
            ha._g_prev, ha._t_prev = ha.g_now, ha._t_last
            ha.g_now, ha._t_last = ({names[0]: g1} if len(names) == 1 else {names[0]: g1, names[1]: g2}), t
            if ha.pending_draws:
                ha.pending_draws = []
            if c == OUT_RELEASE:
                if vid in controlled:
                    controlled.discard(vid)
                    cmds.append(Release(vid))
                continue
            if c == OUT_FALLBACK:
                self._fallback(t, vid, cmds)
                continue
            if c == OUT_COMMAND_GAP and gap < self.min_virtual_gap:  # Python's min(min_virtual_gap, gap)
                self.min_virtual_gap = gap
            if hold and vid not in controlled and s["ramp"].item(live[vid]):
                cmds.append(SetLaneChangeMode(vid, HOLD_LANE_MODE))
            cmds.append(SetSpeed(vid, v_next, mode_cmd))
            controlled.add(vid)
            self.commands_sent += 1

    def _decide_py(self, t: float, s: dict[str, Any], target: float, items: list[tuple[str, tuple[float, Assignment]]],
                   cmds: list[Any]) -> None:
        """The decisions of the vehicles ``items`` (vehicle, (arrival, assignment)) in Python, in order. The rows'
        columns are read per vehicle as Python scalars (``item``: the same floats; a ``tolist`` of every column
        cost more for the ~4 vehicles of a tick)."""
        length = s["length"]
        dist, speed = s["dist"].item, s["speed"].item
        lim = self.p.limits
        a_min, a_max = lim.a_min_mps2, lim.a_max_mps2
        live = s["row"]
        controlled, assigned, automata = self.controlled, self.assigned, self.automata
        ramp_l, right_l, merged_l = s["ramp"].item, s["right"].item, s["merged"].item
        quiet, mode_flags, safety = self._quiet, self._mode_flags, self.safety
        # _physical_leader_cap's and _command_speed's steps inline, unless the cap is wrapped on the instance
        # (tools/trace_hard_brakes; the tests' reference)
        cap_inline = "_physical_leader_cap" not in self.__dict__
        leader = s.get("leader")
        if leader is None and cap_inline:  # a state without the CAM stage's (_physical_leader_cap)
            leader = s["leader"] = lane_leaders(s["lane"], s["lane_pos"])
        lane_pos, len_at = s["lane_pos"].item, length.item
        v_max, a_down, period = lim.v_max_mps, lim.a_min_mps2 * self.period, self.period
        for vid, (_t_recv, a) in items:
            k = live.get(vid)
            if k is None:
                continue
            d_k = dist(k)
            if d_k < 0:
                continue
            ramp_k = ramp_l(k)
            # changed to the left lane, or a ramp vehicle that moved over: out of the conflict
            if not (ramp_k or right_l(k)) or merged_l(k):
                if vid in controlled:
                    controlled.discard(vid)
                    cmds.append(Release(vid))
                del assigned[vid]
                automata.pop(vid, None)
                continue
            if t - a.t_sent_s > self.p.stale_after_s:  # the RSU went quiet: onboard car-following
                self._fallback(t, vid, cmds)
                continue
            road_k = "ramp" if ramp_k else "main"
            pred = a.pred
            cross_pred = pred is not None and a.pred_road != road_k
            x = MergeState(road_k, d_k, cross_pred,
                           probe=lambda vid=vid, pred=pred, d_k=d_k: self._virtual_gap(t, vid, pred, d_k, live, length),
                           cross_ahead=a.cross_ahead is not None and not cross_pred)
            ha = self._automaton(vid, road_k)  # every tick (tools/trace_hard_brakes wraps it per vehicle)
            # most ticks no guard fires (then the general update); quiet_update written out when it applies
            if not (quiet(ha, t, x) if quiet.usable(ha) else ha.quiet_update(t, x)):
                ha.update(t, x, self.events, settle=3)
            flags = mode_flags.get(ha.mode)
            if flags is None:
                path = ha.path()
                flags = mode_flags[ha.mode] = ("merge" in path or "yield" in path, "early" in path,
                                               "behind" in path or "open" in path)
            near_merge, early, keeps_gap = flags
            v_k = speed(k)
            # before virtual following starts: open the gap to a predecessor from the other road early,
            # comfortably (None: no braking needed, or no track of it)
            pre_open = self._pre_opening_accel(x, v_k) if cross_pred and not near_merge else None
            if early:  # open early to the ramp vehicle ahead of the mainline predecessor
                ahead = self._virtual_gap(t, vid, a.cross_ahead, d_k, live, length)
                pre_open = self._pre_opening_accel(MergeState(road_k, d_k, True, _gap=ahead), v_k)
            if road_k == "main" and not near_merge and pre_open is None:
                # a mainline vehicle behind a mainline predecessor follows its physical leader, which
                # is that predecessor: its own driver (SUMO) does that; only gap openers are commanded
                if vid in controlled:
                    controlled.discard(vid)
                    cmds.append(Release(vid))
                continue
            if near_merge:  # virtual-vehicle following: cruise, bounded below by the order predecessor
                acc = min(max(target - v_k, a_min), a_max)  # np.clip
            elif road_k == "main":  # early gap opening behind a ramp predecessor
                acc = float(pre_open)  # type: ignore[arg-type]
            else:  # a ramp vehicle on the ramp: energy-optimal arrival at its assigned crossing time
                acc = merge_accel(-d_k, v_k, t, a.t_cross_s, 0.0, target, lim)
                if pre_open is not None:  # ... and early gap opening behind a mainline predecessor
                    acc = min(acc, pre_open)
            if near_merge and cross_pred:
                vg = x.gap()
                if not vg.known:
                    self._fallback(t, vid, cmds)
                    continue
                if keeps_gap:  # keep the gap behind the predecessor
                    gap, v_lead = vg.gap_m, max(vg.v_lead_mps, 0.0)
                    self.min_virtual_gap = min(self.min_virtual_gap, gap)
                    if vg.age_s > self.period:  # unheard since: assume it braked as hard as it can
                        x_last = gap - v_lead * vg.age_s
                        gap, v_lead = worst_case_leader(x_last, v_lead, vg.age_s, self.safety.b_lead_mps2)
                        v_lead = max(v_lead, 0.0)
                    acc = self._gap_opening_accel(acc, gap, v_k, v_lead)
            if cap_inline:  # _physical_leader_cap's steps (unless wrapped, e.g. by tools/trace_hard_brakes)
                j = leader.item(k)
                if j >= 0:
                    acc = safe_accel(lane_pos(j) - len_at(j) - lane_pos(k), v_k, speed(j), acc, safety)
            else:
                acc = self._physical_leader_cap(s, k, acc)
            v_next = (min(max(v_k + acc * period, 0.0), max(v_max, v_k + a_down)) if cap_inline  # _command_speed's
                      else self._command_speed(v_k, acc))
            if self.p.hold_lane_change and ramp_k and vid not in controlled:
                cmds.append(SetLaneChangeMode(vid, HOLD_LANE_MODE))
            cmds.append(SetSpeed(vid, v_next, self.p.command_speed_mode))
            controlled.add(vid)
            self.commands_sent += 1
    def _automaton(self, vid: str, road: str) -> HybridAutomaton:
        ha = self.automata.get(vid)
        if ha is None:
            sw = self.p.switching
            rng = self._ctx.rng(f"{self.name}.switching.{vid}") if sw.temperature is not None else None
            if self.clone_automata:  # merge_automaton's, from the road's template
                template = self._ha_templates.get(road)
                if template is None:
                    template = self._ha_templates[road] = merge_automaton(self.name, "", road, self.theta, sw, rng)
                ha = self.automata[vid] = clone_automaton(template, vid, rng)
            else:
                ha = self.automata[vid] = merge_automaton(self.name, vid, road, self.theta, sw, rng)
        return ha

    # age of information at the RSU, sampled per tick over the coordinated vehicles (coord_kernel's state)
    @property
    def _aoi_sum(self) -> float:
        return float(self._aoi_f[F_AOI_SUM])

    @_aoi_sum.setter
    def _aoi_sum(self, v: float) -> None:
        self._aoi_f[F_AOI_SUM] = v

    @property
    def _aoi_max(self) -> float:
        return float(self._aoi_f[F_AOI_MAX])

    @_aoi_max.setter
    def _aoi_max(self, v: float) -> None:
        self._aoi_f[F_AOI_MAX] = v

    @property
    def _aoi_n(self) -> int:
        return int(self._aoi_i[I_AOI_N])

    @_aoi_n.setter
    def _aoi_n(self, v: int) -> None:
        self._aoi_i[I_AOI_N] = v

    @staticmethod
    def _slot_check(p: Params) -> SlotCheck | None:
        """The coordinator's ``slot_feasible`` boundary (None at its default, inf: every slot is feasible)."""
        decel = p.boundaries.slot_feasible.decel_mps2
        if not math.isfinite(decel):
            return None
        return SlotCheck(decel, time_gap_s=p.merge_time_gap_s, s0_m=p.merge_gap_s0_m)

    @property
    def _opens_ahead(self) -> bool:
        """Whether the ``open_ahead`` boundary can hold (its ``dist_m`` > 0; 0, the default, is off)."""
        return self.theta["open_ahead"]["dist_m"] > 0.0

    def _cross_ahead(self, order: list[str], pos: int, road_of: dict[str, str]) -> str | None:
        """The nearest vehicle of the other road ahead in ``order`` of the vehicle at ``pos``, among the
        ``_listen_depth`` vehicles it tracks, when its predecessor is on its own road (else None)."""
        road = road_of.get(order[pos])
        if pos == 0 or road_of.get(order[pos - 1]) != road:
            return None
        for j in range(pos - 2, max(pos - self._listen_depth, 0) - 1, -1):
            if road_of.get(order[j]) not in (None, road):
                return order[j]
        return None

    def _virtual_gap(self, t: float, vid: str, pred: str | None, dist_m: float, live: dict[str, int],
                     length: np.ndarray) -> VirtualGap:
        """``vid``'s V2X track of its predecessor, both projected on the conflict point (not known:
        never heard, or older than ``stale_after_s``)."""
        est = self.tracks.predict_one(vid, pred, t) if pred is not None else None
        if est is None or est[2] > self.p.stale_after_s:
            return VirtualGap(False)
        pos_lead, vel_lead, age_s = est
        lead_len = float(length[live[pred]]) if pred in live else 5.0
        gap = dist_m + pos_lead - lead_len  # > 0: the predecessor is ahead of the ego
        return VirtualGap(True, gap, vel_lead, age_s, lead_len)

    def _physical_leader_cap(self, s: dict[str, Any], k: int, acc: float) -> float:
        """``acc`` capped by the safety layer against the vehicle's own leader on its lane (sensed on
        board).  SUMO's safe-speed check alone did not keep a commanded EIDM vehicle off a stopped
        leader: with the calibrated humans commanded ramp vehicles ran into the ramp's queue at 7 m/s."""
        leader = s.get("leader")
        if leader is None:  # a state without the CAM stage's: every row's lane leader, once
            leader = s["leader"] = lane_leaders(s["lane"], s["lane_pos"])
        j = int(leader[k])
        if j < 0:
            return acc
        cols = s.get("cols")  # _decide's lists (the same floats), else the arrays
        if cols is None:
            cols = s["cols"] = (s["lane_pos"].tolist(), s["length"].tolist(), s["speed"].tolist())
        lane_pos, length, speed = cols
        gap = lane_pos[j] - length[j] - lane_pos[k]
        return safe_accel(gap, speed[k], speed[j], acc, self.safety)

    def _pre_opening_accel(self, x: MergeState, v: float) -> float | None:
        """Early gap opening [m/s²], before the vehicle reaches the distance where it follows its
        predecessor from the other road (``yield_enter`` / ``merge_enter``): the gap-opening rule at
        comfortable braking at most, only when it brakes (None otherwise, or without a track).

        Without it the follower met a predecessor projected a few metres ahead and slower at that
        distance, and the safety layer braked it at 6 m/s² on the first tick (seed 100, 300 s: most of
        the hard brakes that remained with the rule alone bounded)."""
        vg = x.gap()
        if not vg.known:
            return None
        a = max(self._merge_gap_accel(vg.gap_m, v, max(vg.v_lead_mps, 0.0)), self.p.limits.a_min_mps2)
        return a if a < 0.0 else None

    def _gap_opening_accel(self, acc: float, gap_m: float, v: float, v_lead: float) -> float:
        """``acc`` [m/s²] bounded by the gap-opening rule, which brakes at most comfortably
        (``limits.a_min_mps2``), and then by the safety layer, which alone may brake harder (up to its
        ``b_ego``) when the gap to the virtual leader ``gap_m`` [m] requires it.

        Unbounded, the rule asked -6 to -14 m/s² of a follower whose predecessor from the other road
        was put close ahead (seed 100, 300 s: 11 of 34 hard brakes started with such a command and the
        safety layer not binding)."""
        a_gap = max(self._merge_gap_accel(gap_m, v, v_lead), self.p.limits.a_min_mps2)
        return safe_accel(gap_m, v, v_lead, min(acc, a_gap), self.safety)

    def _command_speed(self, v: float, acc: float) -> float:
        """The speed [m/s] commanded for the next period: ``v + acc·period``, at least 0 and at most
        ``limits.v_max_mps``, except that a vehicle above ``v_max`` (a driver's speed factor) comes down
        to it at ``limits.a_min_mps2`` (comfortable braking), not in one step.

        In speed mode 27 SUMO executes any slowing up to the type's emergency decel at once; clipped
        to ``v_max`` in one step, a mainline car at 33.7 m/s was set to 30 m/s (-37 m/s²) by its first
        command. Released at the next tick, its EIDM driver kept braking from that acceleration with its
        jerk limit (-36 m/s², easing 0.6 m/s² a step) to a standstill on the open road, and the car
        behind it ran into it (held-out seed 3805499706 of the merge benchmark, 180 s, at 43 s; 3 of 200
        held-out runs). A braking ``acc`` below ``a_min`` (the safety layer's) is still passed on."""
        lim = self.p.limits
        v_cap = max(lim.v_max_mps, v + lim.a_min_mps2 * self.period)
        return min(max(v + acc * self.period, 0.0), v_cap)

    def _merge_gap_accel(self, gap_m: float, v: float, v_lead: float) -> float:
        """Constant-time-gap rule towards the virtual leader: open the gap that the lane change needs.

        The safety bound alone lets a follower close to a few metres behind a slow virtual leader;
        the merging vehicle then finds no gap it may accept (SUMO's lane-change model wants about
        its car-following gap, ``minGap + v·tau``), both wait for each other and the merge locks up.
        So the follower also tracks ``s0 + v·h`` with the usual ACC gains (Milanés & Shladover 2014).
        """
        g_des = self.p.merge_gap_s0_m + v * self.p.merge_time_gap_s
        return 0.23 * (gap_m - g_des) + 0.07 * 10.0 * (v_lead - v)

    def _fallback(self, t: float, vid: str, cmds: list[Any]) -> None:
        if vid in self.controlled:
            self.controlled.discard(vid)
            cmds.append(Release(vid))
            self.stale_releases += 1
            self.events.emit(t, self.name, "fallback", f"{vid}: stale V2X information, SUMO car-following")

    def _stream_speed(self, s: dict[str, Any]) -> float:
        """Crossing speed: the mean speed of the mainline just upstream of the control zone.

        Measured where no vehicle is controlled yet: a speed measured inside the zone would feed
        the controller's own slowing back into its target (the right lane would spiral down).
        """
        got = s.get("stream")  # (sum, count), found by the compiled CAM stage (cam_kernel: numpy's sum's bits)
        if got is None:
            zone = self.p.coordinator.control_zone_m
            sp = s["speed"][~s["ramp"] & (s["dist"] > zone) & (s["dist"] < zone + 300.0)]
            got = (sp.sum(), len(sp))
        total, n = got
        v = float(total / n) if n else self.p.limits.v_max_mps  # np.mean's bits: its sum / n
        return min(max(v, 8.0), self.p.limits.v_max_mps)  # np.clip's value (v is never NaN)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        st = self.channel.stats()
        aoi_mean = self._aoi_sum / self._aoi_n if self._aoi_n else np.nan
        return {"v2x_delivery_ratio": st.delivery_ratio, "v2x_aoi_mean_s": aoi_mean,
                "v2x_aoi_max_s": self._aoi_max if self._aoi_n else np.nan, "v2x_sent": st.sent, "v2x_fallbacks": self.stale_releases,
                "v2x_dropped_after_end": st.dropped_after_end, "v2x_dropped_overflow": st.dropped_overflow,
                "v2x_commands": self.commands_sent,
                "min_virtual_gap_m": self.min_virtual_gap if math.isfinite(self.min_virtual_gap) else np.nan}


def deliverable_safety(safety: SafetyParams, scenario: Any, command_speed_mode: int, period_s: float) -> SafetyParams:
    """The safety layer's params ``safety`` limited to the braking a commanded vehicle delivers: in speed
    mode ``command_speed_mode`` SUMO executes a commanded slowing up to the type's ``emergencyDecel``
    (mode 27) or only up to its ``decel`` (bit 2 set, e.g. 31), so ``b_ego`` is at most the smallest of
    those of the connected flows' types, and the reaction time at least the period ``period_s`` [s] a
    command is held.  Shared by the V2X merging and wave-damping controllers."""
    road = road_spec(scenario) if scenario is not None else None
    capped = bool(command_speed_mode & 4)
    decels = [(vt.decel if capped else vt.emergency_decel)
              for vt in (road.demand.vehicle_types[f.vtype] for f in road.demand.flows.values()
                         if f.connected_share > 0)] if road is not None else []
    return safety.model_copy(update={"b_ego_mps2": min([safety.b_ego_mps2, *decels]),
                                     "reaction_s": max(safety.reaction_s, period_s)})
