"""Where the V2X merging variants' hard brakes come from (issue 27, diagnosis only: no behaviour change).

    python tools/trace_hard_brakes.py --variant v2x_fifo --variant v2x_cps --seeds 0-7 --out results/hard_brakes

Runs ``scenarios/merging.yaml``'s variants in-process (the scenario's draws for each seed, as
``run_scenario`` does; one process a run: libsumo), watches every hard-brake onset the surrogate-safety
monitor counts (a vehicle's acceleration drops below -4.5 m/s², after the warm-up) and attributes it to
what the merging controller did to that vehicle at the tick before (the command SUMO executed):

- ``commanded``: the controller commanded the vehicle; the binding term of its command (safety layer
  against the virtual leader, against the own (physical) leader, the gap-opening rule, the trajectory /
  cruise), its mode (``approach``/``behind``/``ahead`` on the ramp, ``free``/``open``/``pass`` on the
  mainline; ``pre-opening`` before virtual following), or SUMO braking harder than commanded;
- ``fallback``: handed back to SUMO's driver after stale V2X information, within ``RECENT_S``;
- ``released``: released otherwise (past the conflict point, left the conflict), within ``RECENT_S``;
- ``follower``: a SUMO driver (human or connected but not commanded) whose physical leader was commanded;
- ``other``: a SUMO driver behind a leader that was not commanded.

Writes ``<out>/<variant>-s<seed>.jsonl`` (one onset a line, with the situation: road, lane, distance to
the conflict point, speeds, gaps, the predecessor in the crossing order and when it last changed) and
prints the counts by cause; checks that the onsets counted equal the run's ``hard_brakes``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import tempfile
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "merging.yaml"
HARD_MPS2 = -4.5  # the surrogate-safety monitor's default threshold
RECENT_S = 3.0  # [s] a release this recent still explains a SUMO driver's hard brake
EPS = 1e-9


class Probe:
    """Wraps the merging controller's decision steps to keep, per vehicle, the terms of its last command."""

    def __init__(self, ctl: Any) -> None:
        self.ctl = ctl
        self.t = 0.0
        self.cur: dict[str, dict[str, Any]] = {}  # this tick's decisions, vehicle -> terms
        self.fallback_t: dict[str, float] = {}
        self.pred: dict[str, tuple[str | None, float]] = {}  # vehicle -> (predecessor, since [s])
        self.change: dict[str, dict[str, Any]] = {}  # vehicle -> how its predecessor last changed
        self.seq_before: list[str] = []
        self._vid: str | None = None
        self.state: dict[str, Any] = {}
        for name in ("_sense", "_automaton", "_pre_opening_accel", "_gap_opening_accel", "_physical_leader_cap", "_fallback"):
            setattr(ctl, name, getattr(self, "_w" + name)(getattr(ctl, name)))

    def begin(self, t: float) -> None:
        """Start the tick at ``t`` [s]."""
        self.cur, self.t = {}, t
        self.seq_before = list(self.ctl.coord.sequence)  # the RSU's order before this tick's coordination

    def _change(self, vid: str, old: str | None, new: str | None) -> dict[str, Any]:
        """How the predecessor in the crossing order changed from ``old`` to ``new`` (at assignment: old None)."""
        seq = self.ctl.coord.sequence
        if old is None:
            why = "first assignment"
        elif old not in seq:
            why = "old predecessor left the order (crossed or left the conflict)"
        elif vid in seq and seq.index(old) > seq.index(vid):
            why = "old predecessor now behind (re-sequenced)"
        else:
            why = "a vehicle put between (inserted or re-sequenced)"
        return {"prev_pred": old, "pred_change": why, "prev_pred_fate": self._fate(old),
                "new_pred_was_ordered": new in self.seq_before if new is not None else None}

    def _w_sense(self, f: Any) -> Any:
        def w(ctx: Any) -> Any:
            state = f(ctx)
            self.state = state or {}
            return state
        return w

    def _fate(self, vid: str | None) -> str | None:
        """Where vehicle ``vid`` is now, seen from the conflict point."""
        s = self.state
        k = s.get("row", {}).get(vid) if vid is not None else None
        if vid is None:
            return None
        if k is None:
            return "left the road"
        if s["dist"][k] <= 0.0:
            return "past the conflict point"
        if s["merged"][k]:
            return "merged onto the mainline"
        if not (s["ramp"][k] or s["right"][k]):
            return "moved to the left lane"
        return "still on a conflicting lane"

    def _w_automaton(self, f: Any) -> Any:
        def w(vid: str, road: str) -> Any:
            self._vid = vid
            a = self.ctl.assigned[vid][1]
            p = self.pred.get(vid)
            if p is None or p[0] != a.pred:
                self.pred[vid] = (a.pred, self.t)
                self.change[vid] = self._change(vid, p[0] if p is not None else None, a.pred)
            self.cur[vid] = {"road": road, "pred": a.pred, "pred_road": a.pred_road,
                             "pred_since_s": self.pred[vid][1], **self.change[vid]}
            return f(vid, road)
        return w

    def _w_pre_opening_accel(self, f: Any) -> Any:
        def w(x: Any, v: float) -> Any:
            out = f(x, v)
            self.cur[self._vid or ""]["pre_open"] = out
            return out
        return w

    def _w_gap_opening_accel(self, f: Any) -> Any:
        def w(acc: float, gap_m: float, v: float, v_lead: float) -> float:
            out = f(acc, gap_m, v, v_lead)
            rule = max(self.ctl._merge_gap_accel(gap_m, v, v_lead), self.ctl.p.limits.a_min_mps2)
            self.cur[self._vid or ""].update(gap_in=acc, gap_rule=rule, gap_out=out, vgap_m=gap_m, v_lead=v_lead)
            return out
        return w

    def _w_physical_leader_cap(self, f: Any) -> Any:
        def w(s: dict[str, Any], k: int, acc: float) -> float:
            out = f(s, k, acc)
            rec = self.cur[s["ids"][k]]
            v = float(s["speed"][k])  # the command as _decide sends it: a speed in [0, v_max] (a faster
            v_next = self.ctl._command_speed(v, out)  # vehicle comes down to v_max comfortably)
            rec.update(cap_in=acc, cap_out=out, a_sent=(v_next - v) / self.ctl.period, commanded=True)
            ha = self.ctl.automata.get(s["ids"][k])
            rec["ha_mode"] = ha.mode if ha is not None else None
            j = int(s["leader"][k])
            rec["own_gap_m"] = float(s["lane_pos"][j] - s["length"][j] - s["lane_pos"][k]) if j >= 0 else None
            return out
        return w

    def _w_fallback(self, f: Any) -> Any:
        def w(t: float, vid: str, cmds: list[Any]) -> None:
            if vid in self.ctl.controlled:
                self.fallback_t[vid] = t
            f(t, vid, cmds)
        return w


def cause(rec: dict[str, Any] | None) -> tuple[str, str]:
    """(cause, mode) of a commanded vehicle's hard brake from the terms of its last command."""
    if rec is None or not rec.get("commanded"):
        return "", ""
    mode = str(rec.get("ha_mode"))
    if mode in ("approach", "free") and rec.get("pre_open") is not None:
        mode += "/pre-opening"
    if rec["a_sent"] > HARD_MPS2:
        return "SUMO braked harder than commanded", mode
    if rec["cap_out"] > HARD_MPS2:
        return "speed command clipped to v_max", mode
    if rec["cap_out"] < rec["cap_in"] - EPS:
        return "safety layer: own leader", mode
    if "gap_out" in rec and rec["gap_out"] < min(rec["gap_in"], rec["gap_rule"]) - EPS:
        return "safety layer: virtual leader", mode
    if "gap_out" in rec and rec["gap_rule"] <= rec["gap_in"]:
        return "gap-opening rule", mode
    return "trajectory / cruise", mode


def trace(variant: str, seed: int, duration_s: float | None, out: Path) -> dict[str, Any]:
    """One run: its hard-brake onsets, attributed, written to ``out``; returns counts and the metric."""
    from corridor.batch import draws_for
    from corridor.controllers.merging.safety_layer import lane_leaders
    from corridor.run import build
    from corridor.scenario import apply_overrides, load, validate
    from corridor.snapshot import Role

    sets = [f"duration={duration_s}"] if duration_s else []
    sc, raw = load(SCENARIO, sets)
    sim = build(validate(apply_overrides(raw, {**sc.sweep[variant], **draws_for(sc, seed)}), variant), seed,
                Path(tempfile.mkdtemp()))
    ctx = sim.ctx
    sim.start()
    ctl = ctx.components["merge"]
    probe = Probe(ctl)
    braking: dict[str, bool] = {}
    controlled_before: set[str] = set()
    released_t: dict[str, float] = {}
    rows: list[dict[str, Any]] = []
    try:
        for _ in range(sim.n_ticks):
            # one tick: decide on the last state, act, SUMO steps, the monitors see the new state, so
            # an onset seen after the tick comes from this tick's commands
            probe.begin(ctx.t)
            sim.step()
            for vid in controlled_before - ctl.controlled:
                released_t[vid] = ctx.t
            controlled_before = set(ctl.controlled)
            road, snap = ctx.snapshot.road, ctx.snapshot
            ids = list(snap.ids[road.sl])
            accel = np.asarray(road.accel)
            hard = np.flatnonzero(accel < HARD_MPS2).tolist()
            onsets = [k for k in hard if not braking.get(ids[k], False)]
            braking = {ids[k]: True for k in hard}
            if onsets and ctx.t >= sc.warmup:
                situ = Situation(ctx.t, ids, road, snap, lane_leaders(road.lane, road.lane_pos), float(ctl.x_merge),
                                 Role.RAMP)
                rows.extend(onset_row(situ, k, probe, released_t, controlled_before) for k in onsets)
        metrics = sim.finish()
    finally:
        sim.close()
    with (out / f"{variant}-s{seed}.jsonl").open("w") as fh:
        for r in rows:
            fh.write(json.dumps(r) + "\n")
    return {"variant": variant, "seed": seed, "hard_brakes": metrics["hard_brakes"], "onsets": len(rows),
            "by_cause": dict(Counter(r["cause"] for r in rows)),
            "by_cause_mode": dict(Counter(f"{r['cause']} | {r['mode']}" for r in rows))}


@dataclass
class Situation:
    """The state after a tick, as the monitors see it."""

    t: float  # [s]
    ids: list[str]
    road: Any  # the snapshot's road frame
    snap: Any  # the snapshot
    lead: np.ndarray  # per row: the row of the leader on the same lane (-1: none)
    x_merge: float  # [m] x of the conflict point
    ramp_role: Any


def onset_row(s: Situation, k: int, probe: Probe, released_t: dict[str, float], controlled: set[str]
              ) -> dict[str, Any]:
    """One hard-brake onset of the vehicle in row ``k``, attributed."""
    road, snap, t = s.road, s.snap, s.t
    vid = s.ids[k]
    j = int(s.lead[k])
    leader = s.ids[j] if j >= 0 else None
    rec = probe.cur.get(vid)
    c, mode = cause(rec)
    if not c:
        if t - probe.fallback_t.get(vid, -1e9) <= RECENT_S + EPS:
            c = "fallback (stale V2X) -> SUMO driver"
        elif t - released_t.get(vid, -1e9) <= RECENT_S + EPS:
            c = "released -> SUMO driver"
        elif leader is not None and leader in controlled:
            c = "SUMO driver behind a commanded leader"
        else:
            c = "SUMO driver, leader not commanded"
    tb, speed, row_of = road.tables, snap.speed[road.sl], road.offset
    row = {"t": round(t, 2), "vid": vid, "accel": round(float(road.accel[k]), 2), "speed": round(float(speed[k]), 2),
           "route": "ramp" if tb.role[road.uid[k]] == s.ramp_role else "main",
           "connected": bool(tb.connected[road.uid[k]]), "lane": tb.lane_names[road.lane[k]],
           "x_to_conflict_m": round(s.x_merge - float(snap.position[row_of + k, 0]), 1),
           "leader": leader, "leader_speed": round(float(speed[j]), 2) if j >= 0 else None,
           "own_gap_m": (round(float(road.lane_pos[j] - snap.size[row_of + j, 0] - road.lane_pos[k]), 1)
                         if j >= 0 else None),
           "cause": c, "mode": mode}
    if rec is not None:
        row.update({key: (round(v, 3) if isinstance(v, float) else v) for key, v in rec.items()})
        row["pred_changed_s_ago"] = round(t - rec["pred_since_s"], 2)
    return row


def seeds_of(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", required=True)
    ap.add_argument("--seeds", default="0-7", help="a seed or a range a-b")
    ap.add_argument("--duration", type=float, default=None, help="[s] (default: the scenario's)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "hard_brakes")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    jobs = [(v, s) for s in seeds_of(a.seeds) for v in a.variant]
    with ProcessPoolExecutor(max_workers=a.workers, mp_context=multiprocessing.get_context("spawn"),
                             max_tasks_per_child=1) as pool:
        futs = [pool.submit(trace, v, s, a.duration, a.out) for v, s in jobs]
        for f in futs:
            r = f.result()
            print(json.dumps(r), flush=True)
            with (a.out / "summary.jsonl").open("a") as fh:
                fh.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
