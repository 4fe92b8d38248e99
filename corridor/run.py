"""One run: raw scenario + overrides + seed -> Simulation -> one results row.

``execute`` is the function every executor calls (process pool or Ray); it never raises: a run that
fails is a row with ``status=error`` and a one-line message, so a batch always goes on.
"""

from __future__ import annotations

import math
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from corridor.engine import Component, RunContext, Simulation, path_inside
from corridor.errors import CorridorError
from corridor.events import Event, EventLog
from corridor.registry import BACKENDS, CONTROLLERS, MONITORS, RECORDERS
from corridor.scenario import ComponentSpec, Scenario, apply_overrides, scenario_dir, validate
from corridor.shards import ShardComm, run_sharded
from corridor.tick_profile import TickProfile

DEFAULT_MONITORS: dict[str, ComponentSpec] = {"collisions": ComponentSpec(type="collisions")}
# added last when the scenario declares ``specs``: evaluates them on the recorded signals at the end
SPEC_MONITOR = ("stl_specs", ComponentSpec(type="stl_specs"))


@dataclass(frozen=True)
class RunSpec:
    run_id: str
    scenario: str  # scenario name
    source: str  # file the scenario came from (for error messages)
    variant: str
    seed: int
    base: dict[str, Any]  # raw scenario data (extends resolved, --set applied)
    overrides: dict[str, Any] = field(default_factory=dict)  # variant overrides then randomize draws
    draws: dict[str, Any] = field(default_factory=dict)
    out_dir: str | None = None  # where per-run signals go (signals/<run_id>.npz)
    rerun_path: str | None = None  # record this run to a Rerun .rrd file
    base_dir: str | None = None  # the scenario file's folder (files it names are relative to it);
    #   None: the folder of ``source``

    def scenario_folder(self) -> Path:
        return Path(self.base_dir) if self.base_dir else Path(self.source).resolve().parent


def make_component(table: str, name: str, spec: ComponentSpec, sc: Scenario) -> Component:
    registry = {"backends": BACKENDS, "controllers": CONTROLLERS, "monitors": MONITORS}[table]
    cls = registry.get(spec.type)
    params_model = getattr(cls, "Params", None)
    params = params_model.model_validate(spec.params) if params_model else spec.params
    comp: Component = cls(name, params, sc)
    comp.period_override = spec.period  # resolved by the engine at build, before period_source
    return comp


def build(sc: Scenario, seed: int, workdir: Path, rerun_path: str | None = None,
          out_dir: str | Path | None = None, run_id: str = "run") -> Simulation:
    """Assemble backends, controllers, monitors and recorders for one run; components write their
    files under ``out_dir`` through ``RunContext.output_path`` (the scratch ``workdir`` if None).
    ``workdir`` is a run's own scratch folder (a backend writes its input files there, e.g. SUMO's
    ``routes.rou.xml``): never the current directory."""
    if Path(workdir).resolve() == Path.cwd().resolve():
        raise ValueError("build(): the workdir is the current directory; give a scratch folder (e.g. "
                         "tempfile.TemporaryDirectory()), backends write their input files there")
    comps: list[Component] = []
    for name, spec in sc.backends.items():
        comps.append(make_component("backends", name, spec, sc))
    for name, spec in sc.controllers.items():
        if spec.type != "none":
            comps.append(make_component("controllers", name, spec, sc))
    # monitors a component cannot do without (the road backend's trip bookkeeping, say) come right
    # after the defaults, unless the scenario declares a monitor of that name itself
    required = {name: ComponentSpec(type=t) for c in comps for name, t in getattr(c, "required_monitors", {}).items()}
    for name, spec in {**DEFAULT_MONITORS, **required, **sc.monitors}.items():
        comps.append(make_component("monitors", name, spec, sc))
    if rerun_path:
        comps.append(RECORDERS.get("rerun")("rerun", sc, rerun_path))
    if sc.specs:  # last: its finish() reads every signal the others recorded, their finish() included
        comps.append(make_component("monitors", SPEC_MONITOR[0], SPEC_MONITOR[1], sc))
    ctx = RunContext(run_seed=seed, dt=sc.dt, duration=sc.duration, scenario=sc, workdir=workdir,
                     out_dir=Path(out_dir) if out_dir else None, run_id=run_id)
    return Simulation(ctx, comps)


SCRATCH = ".tmp"  # a batch folder's per-run scratch folders (removed when the batch folder is next opened)


def scratch_root(out_dir: str | Path | None) -> Path | None:
    """Where a run's scratch folder goes: under the batch folder (``DIR/.tmp``), so that a run killed
    mid-way leaves nothing in the system temp folder; the system temp folder without a batch."""
    if out_dir is None:
        return None
    root = Path(out_dir) / SCRATCH
    root.mkdir(parents=True, exist_ok=True)
    return root


def event_counts(ctx: RunContext) -> dict[str, int]:
    """The row's event columns (``events_mode``, ``events_fallback``)."""
    return {f"events_{kind}": ctx.events.counts.get(kind, 0) for kind in ("mode", "fallback")}


def switch_scores(ctx: RunContext) -> dict[str, float]:
    """Stochastic boundary switching (``corridor.modes.SwitchingParams``): the number of draws and
    the summed score-function gradient per boundary parameter; nothing when no switch was drawn."""
    draws = ctx.events.of_kind("switch_draw")
    if not draws:
        return {}
    out: dict[str, float] = {"blrl.draws": float(len(draws))}
    for e in draws:
        for k, v in e.data["score"].items():
            col = f"blrl.score.{e.source}.{k}"  # k: boundary.param (every boundary sharing the draw)
            out[col] = out.get(col, 0.0) + float(v)
    return out


class ScratchRun:
    """A run stepped from outside (the Gymnasium and PettingZoo environments): the scenario ``raw``
    with ``overrides`` built for ``seed`` in its own scratch folder; ``close`` ends the simulation and
    removes the folder together."""

    def __init__(self, path: Path, raw: dict[str, Any], overrides: dict[str, Any], seed: int) -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix="corridor-env-")
        try:
            with scenario_dir(path.parent):
                self.sc = validate(apply_overrides(raw, overrides), f"{path} [env]")
                self.sim = build(self.sc, seed, Path(self._tmp.name))
        except BaseException:
            self._tmp.cleanup()
            raise

    def close(self) -> None:
        self.sim.close()
        self._tmp.cleanup()


def _run_rank(sim: Simulation, comm: ShardComm) -> tuple[dict[str, Any], list[Event]]:
    """One rank of a sharded run (``corridor.shards``); a profiled run's ranks measure their round trip
    first and gather their profiles at the end (in ``ctx.profiles``)."""
    sim.ctx.shard = comm
    if sim.ctx.profile is not None:
        sim.ctx.profile.rtt_s = comm.round_trip()
    metrics = sim.run()
    if sim.ctx.profile is not None:
        sim.ctx.profiles = comm.allgather(sim.ctx.profile.summary())
    return metrics, sim.ctx.events.events


def _spawned_rank(sc: Scenario, seed: int, run_id: str, profile: bool, comm: ShardComm
                  ) -> tuple[dict[str, Any], list[Event]]:
    """Ranks 1.. of a sharded run: the same scenario and seed, no recorder, no output files."""
    with tempfile.TemporaryDirectory(prefix="corridor-") as tmp:
        sim = build(sc, seed, Path(tmp), run_id=run_id)
        sim.ctx.profile = TickProfile() if profile else None
        return _run_rank(sim, comm)


def _run(sim: Simulation, sc: Scenario, seed: int, run_id: str) -> dict[str, Any]:
    """The simulation's metrics; in ``shard_count`` processes when a component asks for shards."""
    size = max(c.shard_count for c in sim.ctx.components.values())
    if size <= 1:
        metrics = sim.run()
        if sim.ctx.profile is not None:
            sim.ctx.profiles = [sim.ctx.profile.summary()]
        return metrics
    others = partial(_spawned_rank, sc, seed, run_id, sim.ctx.profile is not None)
    metrics, events, comm = run_sharded(partial(_run_rank, sim), others, size)
    log = EventLog()
    for e in events:
        log.emit(e.t, e.source, e.kind, e.message, **e.data)
    sim.ctx.events = log
    return metrics


def simulate(sc: Scenario, seed: int, out_dir: str | None = None, run_id: str = "run",
             rerun_path: str | None = None, profile: bool = False) -> tuple[dict[str, Any], RunContext, float]:
    """One run: its metrics, its context and its wall time [s]. ``profile``: every rank's CPU per tick
    and part in ``ctx.profiles`` (``corridor.tick_profile``; the rows do not change)."""
    with tempfile.TemporaryDirectory(prefix="corridor-", dir=scratch_root(out_dir)) as tmp:
        sim = build(sc, seed, Path(tmp), rerun_path, out_dir, run_id)
        sim.ctx.profile = TickProfile() if profile else None
        metrics = _run(sim, sc, seed, run_id)
    metrics.update(event_counts(sim.ctx))
    metrics.update(switch_scores(sim.ctx))
    if out_dir and sc.outputs.signals:
        sig_dir = Path(out_dir) / "signals"
        sig_dir.mkdir(parents=True, exist_ok=True)
        path = path_inside(sig_dir, f"{run_id}.npz")  # a run id with a '/' or '..' cannot lead out
        if path.parent != sig_dir.resolve():
            raise ValueError(f"run id {run_id!r} is not a plain file name")
        arrays: dict[str, Any] = sim.ctx.signals.as_arrays()
        np.savez_compressed(path, **arrays)
    return metrics, sim.ctx, sim.wall_s


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    msg = text[0] if text else ""
    return f"{type(exc).__name__}: {msg}" if not isinstance(exc, CorridorError) else msg


def execute(spec: RunSpec) -> dict[str, Any]:
    """Run one RunSpec; always returns a row."""
    t0 = time.perf_counter()
    row: dict[str, Any] = {"run_id": spec.run_id, "scenario": spec.scenario, "variant": spec.variant,
                           "seed": spec.seed, "status": "ok", "error": ""}
    row.update({f"draw.{k}": v for k, v in spec.draws.items()})
    try:
        with scenario_dir(spec.scenario_folder()):  # the components re-validate their params at build
            sc = validate(apply_overrides(spec.base, spec.overrides), f"{spec.source} [{spec.variant}]")
            metrics, _, _ = simulate(sc, spec.seed, spec.out_dir, spec.run_id, spec.rerun_path)
        row["sim_s"] = sc.duration
        row.update(metrics)
    except Exception as exc:  # a failing run is a row, never a lost batch
        row.update(status="error", error=one_line(exc), sim_s=math.nan)
        row["traceback"] = traceback.format_exc(limit=6)
    row["wall_s"] = time.perf_counter() - t0
    return row
