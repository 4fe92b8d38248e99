"""The engine: a base tick, multi-rate components, and the pipeline of one tick.

Every tick:  sense → communicate → decide → act → integrate → detect → record.
Each component declares its ``phase`` and its ``period`` (a whole multiple of the base tick ``dt``)
and runs only on the ticks where its period is due.  Backends (SUMO, JSBSim) own dynamics and run in
*integrate*; controllers run in *decide* and emit commands that the backends apply in *act*; monitors
run in *detect* on the world snapshot; recorders (signals, Rerun) run in *record* and never change a
trajectory.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path, PurePath
from typing import Any, ClassVar

import numpy as np

from corridor.events import EventLog
from corridor.snapshot import WorldSnapshot
from corridor.tick_profile import TickProfile


class Phase(IntEnum):
    """The stages of a tick, in the order they run (a component declares one as its ``phase``)."""

    SENSE = 0
    COMMUNICATE = 1
    DECIDE = 2
    ACT = 3
    INTEGRATE = 4
    DETECT = 5
    RECORD = 6


def relative_output_path(text: str) -> str:
    """Check an output file name of a scenario: relative, no ``..`` component, not empty.

    The run resolves it under its output folder.

    Returns:
        ``text`` unchanged.

    Raises:
        ValueError: one line saying what is wrong with the path.
    """
    p = PurePath(text)
    if not text.strip() or not p.parts:
        raise ValueError("must be a file name relative to the run's output folder, got an empty path")
    if p.is_absolute() or text.startswith(("/", "\\", "~")) or (len(text) > 1 and text[1] == ":"):
        raise ValueError(f"must be a path relative to the run's output folder (--out), got {text!r}")
    if ".." in p.parts or ".." in PurePath(text.replace("\\", "/")).parts:
        raise ValueError(f"must stay inside the run's output folder: no '..' component allowed, got {text!r}")
    return text


def path_inside(root: str | Path, rel: str | PurePath) -> Path:
    """``root / rel`` resolved (symlinks followed), refused unless it lies inside ``root``."""
    base = Path(root).resolve()
    out = (base / rel).resolve()
    if out != base and base not in out.parents:
        raise ValueError(f"output path {str(rel)!r} escapes the output folder {str(base)!r}")
    return out


def stable_key(name: str) -> int:
    """A process-independent integer for a name (Python's ``hash`` is salted per process)."""
    return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=4).digest(), "little")


class Signals:
    """Named scalar time series recorded during a run (the input of STL specs and report plots)."""

    def __init__(self) -> None:
        self._t: dict[str, list[float]] = {}
        self._v: dict[str, list[float]] = {}

    def record(self, name: str, t: float, value: float) -> None:
        """Append one point ``(t [s], value)`` to the series ``name``."""
        self._t.setdefault(name, []).append(t)
        self._v.setdefault(name, []).append(float(value))

    def record_many(self, name: str, t: Iterable[float], values: Iterable[float]) -> None:
        """Several points of one series at once, in time order (a monitor that processes ticks in blocks)."""
        self._t.setdefault(name, []).extend(map(float, t))
        self._v.setdefault(name, []).extend(map(float, values))

    def names(self) -> list[str]:
        """The names of the recorded series, in the order they were first recorded."""
        return list(self._v)

    def get(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """One series as ``(times [s], values)``."""
        return np.asarray(self._t[name]), np.asarray(self._v[name])

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Every series as ``{name: values, name.t: times [s]}`` (the layout of ``signals/<run_id>.npz``)."""
        out: dict[str, np.ndarray] = {}
        for n in self._v:
            out[f"{n}.t"] = np.asarray(self._t[n])
            out[n] = np.asarray(self._v[n])
        return out


@dataclass
class RunContext:
    """What components see: time, the snapshot, the command bus, events, signals, and their peers."""

    run_seed: int
    dt: float  # [s]
    duration: float  # [s]
    t: float = 0.0  # [s]
    tick: int = 0
    snapshot: WorldSnapshot = field(default_factory=WorldSnapshot)
    commands: list[Any] = field(default_factory=list)
    events: EventLog = field(default_factory=EventLog)
    signals: Signals = field(default_factory=Signals)
    components: dict[str, Component] = field(default_factory=dict)
    scenario: Any = None
    workdir: Any = None  # a per-run scratch directory (pathlib.Path)
    out_dir: Path | None = None  # the batch's output folder (--out); None: files go to workdir
    run_id: str = "run"  # e.g. "none-s0"; part of every per-run file name
    shard: Any = None  # a sharded run's corridor.shards.ShardComm (this process's rank); None: one process
    profile: TickProfile | None = None  # opt-in: CPU per tick and part (corridor.tick_profile)
    profiles: list[dict[str, Any]] | None = None  # a profiled run: every rank's TickProfile.summary(), rank order

    def output_path(self, rel: str | Path, per_run: bool = True) -> Path:
        """Where a component writes the file ``rel`` (relative, checked by ``relative_output_path``).

        The file lies under the batch's output folder (the scratch workdir when there is none), with
        the run id added to the file name (``mavlink/link.tlog`` -> ``mavlink/link-none-s0.tlog``) so
        the runs of a batch never overwrite each other. The parent folders are created.

        Raises:
            ValueError: the path would leave the folder (``..``, an absolute path, a symlink pointing out).
        """
        target = PurePath(relative_output_path(str(rel)))
        if per_run:
            target = target.with_name(f"{target.stem}-{self.run_id}{target.suffix}")
        root = self.out_dir if self.out_dir is not None else self.workdir
        if root is None:
            raise ValueError(f"no output folder for {str(target)!r}")
        out = path_inside(root, target)
        out.parent.mkdir(parents=True, exist_ok=True)
        return path_inside(root, target)  # again after mkdir: a symlinked folder cannot lead out

    def part(self, name: str) -> AbstractContextManager[None]:
        """A part of the tick (a component's tick, or a stage inside one), timed when profiled.

        Nested parts count apart from the one around them (``corridor.tick_profile``).
        """
        return self.profile.part(name) if self.profile is not None else nullcontext()

    def rng(self, name: str) -> np.random.Generator:
        """An independent generator per subsystem, derived from the run seed and the name only.

        Adding a component therefore never changes another one's random stream.
        """
        return np.random.default_rng(np.random.SeedSequence(self.run_seed, spawn_key=(stable_key(name),)))

    def get(self, name: str) -> Component:
        """The component called ``name``."""
        return self.components[name]

    def backends(self) -> list[Backend]:
        """The run's backends, in build order."""
        return [c for c in self.components.values() if isinstance(c, Backend)]


@dataclass(frozen=True)
class Metric:
    """A column a component's ``finish`` writes, as the report's glossary and verdict read it.

    ``name``: the column (``*`` stands for any text: ``nmac_*`` covers ``nmac_uav_uav``, ...);
    ``unit``: SI with the unit's name (``m``, ``s``, ``m/s``, ``rad``, ``veh``, ``1`` for a count or a
    ratio); ``meaning``: one sentence; ``safety_event``: the column counts safety events (a collision,
    an NMAC, a loss of separation): a run with a value > 0 had one, and the report's verdict counts it.
    """

    name: str
    unit: str
    meaning: str
    safety_event: bool = False


@dataclass(frozen=True)
class Need:
    """A peer a component needs, resolved by the engine at build (``Simulation.__init__``).

    ``role``: the peer must provide it (``Component.provides``). Without ``name_at`` the run must hold
    exactly one provider of the role; with ``name_at`` (an attribute path on the needing component,
    e.g. ``"p.ego"``, normally one of its params) the peer is the component of that name, and must
    provide the role.  ``optional``: no peer (the attribute is None) when the name is None or names no
    component, or when no component provides the role.  ``hint`` ends the error message of a missing
    peer (what to add to the scenario).
    """

    role: str
    name_at: str | None = None
    optional: bool = False
    hint: str = ""


def attr_path(obj: Any, path: str) -> Any:
    """``obj.a.b`` for ``path = "a.b"``."""
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


class Component:
    """Base of everything the engine schedules.

    Peers and the period are declared, and resolved by the engine at build, before any ``setup``:

    * ``needs``: ``{attribute: Need(...)}``; the engine sets each resolved peer as that attribute and
      sets up providers before the components that need them;
    * ``provides``: the roles this component plays for others (``"road"``, ``"trips"``, ...);
    * ``period_source``: where the period comes from: ``"dt"`` (the base tick), ``"run"`` (one tick
      per run, at t = 0), ``"peer:<need>"`` (the period of that peer), an attribute path on the
      component (``"p.tick_s"``: a params field), or None (the ``period`` declared on the class).  The
      scenario's ``period:`` (``period_override``) takes precedence; the result must be a whole
      multiple of ``dt``.
    """

    phase: Phase = Phase.DECIDE
    period: float = 0.1  # [s]
    needs: ClassVar[dict[str, Need]] = {}
    provides: ClassVar[frozenset[str]] = frozenset()
    period_source: ClassVar[str | None] = None
    period_override: float | None = None  # [s] the scenario's ``period:`` of this component
    # the columns ``finish`` writes (report glossary and verdict); None: not declared, () : none
    metrics: ClassVar[tuple[Metric, ...] | None] = None
    # processes the run asks for (corridor.shards: every rank steps the world, sharded components
    # divide their work); the run takes the largest of its components'
    shard_count: int = 1

    def __init__(self, name: str) -> None:
        self.name = name

    def setup(self, ctx: RunContext) -> None:
        """Called once, after every component exists and its peers are set (draw generators, ...)."""

    def tick(self, ctx: RunContext) -> None:
        """Called on every tick where the period is due."""

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        """Called once at the end; returns metric columns for the run's row."""
        return {}

    def metric_columns(self) -> frozenset[str]:
        """Columns ``finish`` always writes.

        Declared so that two components claiming one column are refused at build (naming both)
        rather than when the run ends; undeclared columns are still checked when the metrics are
        merged.
        """
        return frozenset()

    def close(self) -> None:
        """Release external resources; called even when the run failed."""


class Backend(Component):
    """Owns dynamics and hides its library: spawn, apply commands, step, read state."""

    phase = Phase.INTEGRATE

    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        """Apply the commands addressed to entities of this backend (ignore the others)."""

    def snapshot_part(self) -> WorldSnapshot:
        """This backend's rows of the world snapshot after the step (positions in ENU [m], ...)."""
        return WorldSnapshot()

    def static_part(self) -> WorldSnapshot:
        """What is known before the first step, without rows.

        A road backend returns its road frame with the run's static tables and landmarks; the engine
        puts it in ``ctx.snapshot`` before ``setup``.
        """
        return WorldSnapshot()


class Controller(Component):
    """A controller: ``reset(rng)``, ``observe(ctx) -> obs``, ``step(obs) -> commands``.

    ``step`` is pure with respect to the engine (testable alone, do-mpc's ``make_step``); the engine
    glue (``tick``) observes, steps, and puts the commands on the bus.
    """

    phase = Phase.DECIDE

    def setup(self, ctx: RunContext) -> None:
        """Keep the run's event log and draw the controller's own generator (``ctx.rng(name)``)."""
        self.events = ctx.events
        self.reset(ctx.rng(self.name))

    def reset(self, rng: np.random.Generator) -> None:
        """Start afresh with the generator ``rng`` (kept as ``self.rng``)."""
        self.rng = rng

    def observe(self, ctx: RunContext) -> Any:
        """What ``step`` decides on, read from the context (by default the world snapshot)."""
        return ctx.snapshot

    def step(self, obs: Any) -> list[Any]:
        """The commands for this period, from the observation alone (by default none)."""
        return []

    def tick(self, ctx: RunContext) -> None:
        """Observe, step, and put the commands on the bus (the backends apply them in *act*)."""
        ctx.commands.extend(self.step(self.observe(ctx)))


class NoController(Controller):
    """Leaves everything to the backends' own behaviour (e.g. SUMO's default merging)."""

    def __init__(self, name: str, params: Any = None, scenario: Any = None) -> None:
        super().__init__(name)


def _column_owners(comps: list[Component]) -> dict[str, str]:
    """Column -> the component that declares it; a column two components declare is a ValueError."""
    owner: dict[str, str] = {}
    for c in comps:
        for col in sorted(c.metric_columns()):
            if col in owner:
                raise ValueError(f"metric column {col!r} is declared by both {owner[col]!r} and {c.name!r}: "
                                 "give one of them a column prefix (e.g. params: {prefix: 'ramp.'})")
            owner[col] = c.name
    return owner


def merge_metrics(metrics: dict[str, Any], owner: dict[str, str], new: dict[str, Any], source: str) -> None:
    """Add ``source``'s metric columns to ``metrics``.

    A column another component already wrote (``owner``: column -> component) is never silently
    overwritten.

    Raises:
        ValueError: naming the column and both components.
    """
    for key, value in new.items():
        if key in owner:
            raise ValueError(f"metric column {key!r} is written by both {owner[key]!r} and {source!r} "
                             "(give one of them a namespaced name)")
        owner[key] = source
        metrics[key] = value


class Simulation:
    """A base tick and a list of components; ``run`` steps until ``duration``.

    At build it resolves every component's ``needs`` (peers set as attributes), orders ``setup`` so
    that providers come first (otherwise the given order), then resolves every period in that order.
    """

    def __init__(self, ctx: RunContext, components: Iterable[Component]) -> None:
        self.ctx = ctx
        comps = list(components)
        names = [c.name for c in comps]
        if len(set(names)) != len(names):
            raise ValueError(f"component names must be unique: {names}")
        ctx.components = {c.name: c for c in comps}
        _column_owners(comps)  # two components declaring one metric column: refused at build
        self._peers = {c.name: self._resolve_needs(c) for c in comps}
        self.setup_order = self._setup_order(comps)
        for c in self.setup_order:
            for attr, peer in self._peers[c.name].items():
                setattr(c, attr, peer)
            c.period = self._resolve_period(c)
        self._every: dict[str, int] = {c.name: self._ticks_per_period(c) for c in comps}
        self._by_phase: dict[Phase, list[Component]] = {p: [] for p in Phase}
        for c in comps:
            self._by_phase[c.phase].append(c)
        # per phase: (ticks per period, component) in build order, looked up once here, not every tick
        self._due = {p: tuple((self._every[c.name], c) for c in cs) for p, cs in self._by_phase.items()}
        self.wall_s = 0.0
        # the world before the first step: no rows, but the road's static tables and landmarks
        self._backends = [b for b in self._by_phase[Phase.INTEGRATE] if isinstance(b, Backend)]
        ctx.snapshot = WorldSnapshot.from_parts(ctx.t, [b.static_part() for b in self._backends])

    def providers(self, role: str) -> list[Component]:
        """The components that provide ``role``, in build order."""
        return [c for c in self.ctx.components.values() if role in c.provides]

    def provider(self, role: str) -> Component:
        """The one component that provides ``role`` (ValueError if none or several)."""
        found = self.providers(role)
        if len(found) != 1:
            raise ValueError(f"expected one component with role {role!r}, found {[c.name for c in found]}")
        return found[0]

    def _resolve_needs(self, c: Component) -> dict[str, Component | None]:
        out: dict[str, Component | None] = {}
        for attr, need in c.needs.items():
            cands = [p for p in self.providers(need.role) if p is not c]
            cand_names = ", ".join(p.name for p in cands) or "none"
            what = f"{c.name}: need {attr!r} (role {need.role!r})"
            if need.name_at is not None:
                name = attr_path(c, need.name_at)
                peer = self.ctx.components.get(name) if name is not None else None
                if peer is None:
                    if need.optional:
                        out[attr] = None
                        continue
                    raise ValueError(f"{what}: no component named {name!r} ({need.name_at}); "
                                     f"components with that role: {cand_names}")
                if need.role not in peer.provides:
                    roles = ", ".join(sorted(peer.provides)) or "none"
                    raise ValueError(f"{what}: component {name!r} ({need.name_at}) does not provide it "
                                     f"(its roles: {roles}); components with that role: {cand_names}")
                out[attr] = peer
            elif len(cands) == 1:
                out[attr] = cands[0]
            elif not cands:
                if not need.optional:
                    raise ValueError(f"{what}: no component provides it" + (f"; {need.hint}" if need.hint else ""))
                out[attr] = None
            else:
                raise ValueError(f"{what} is ambiguous: candidates {cand_names}")
        return out

    def _setup_order(self, comps: list[Component]) -> list[Component]:
        """Depth first in build order: a component's peers before it; a cycle is an error."""
        order: list[Component] = []
        state: dict[str, int] = {}  # 1: on the path, 2: placed

        def visit(c: Component, path: list[str]) -> None:
            if state.get(c.name) == 2:
                return
            if state.get(c.name) == 1:
                cycle = path[path.index(c.name):] + [c.name]
                raise ValueError(f"component needs form a cycle: {' -> '.join(cycle)}")
            state[c.name] = 1
            for peer in self._peers[c.name].values():
                if peer is not None:
                    visit(peer, [*path, c.name])
            state[c.name] = 2
            order.append(c)

        for c in comps:
            visit(c, [])
        return order

    def _resolve_period(self, c: Component) -> float:
        """The period of ``c`` [s]: the scenario's override, else its ``period_source``."""
        if c.period_override is not None:
            return float(c.period_override)
        src, dt = c.period_source, self.ctx.dt
        if src is None:
            return c.period
        if src == "dt":
            return dt
        if src == "run":
            return dt * max(1, round(self.ctx.duration / dt))
        if src.startswith("peer:"):
            attr = src[len("peer:"):]
            if attr not in c.needs:
                raise ValueError(f"{c.name}: period_source {src!r} names no need (needs: {', '.join(c.needs) or 'none'})")
            peer = getattr(c, attr)
            if peer is None:
                raise ValueError(f"{c.name}: period_source {src!r}: no such peer in this run")
            period: float = peer.period
            return period
        return float(attr_path(c, src))

    def _ticks_per_period(self, c: Component) -> int:
        n = round(c.period / self.ctx.dt)
        if n < 1 or abs(n * self.ctx.dt - c.period) > 1e-9 * max(1.0, c.period):
            raise ValueError(f"{c.name}: period {c.period} s is not a multiple of dt {self.ctx.dt} s")
        return n

    def _run(self, phase: Phase) -> None:
        k = self.ctx.tick
        for every, c in self._due[phase]:
            if k % every == 0:
                with self.ctx.part(c.name):
                    c.tick(self.ctx)

    def _act(self) -> None:
        if self.ctx.commands:
            with self.ctx.part("act"):
                for b in self._backends:
                    b.apply(self.ctx.commands, self.ctx)
                self.ctx.commands = []

    def _integrate(self) -> None:
        self._run(Phase.INTEGRATE)
        self.ctx.tick += 1
        self.ctx.t = self.ctx.tick * self.ctx.dt
        with self.ctx.part("snapshot"):
            self.ctx.snapshot = WorldSnapshot.from_parts(self.ctx.t, [b.snapshot_part() for b in self._backends])

    def step(self) -> None:
        """One tick: sense, communicate, decide, act, integrate, detect, record.

        The pipeline is described in docs/architecture.md ("The tick").
        """
        self._run(Phase.SENSE)
        self._run(Phase.COMMUNICATE)
        self._run(Phase.DECIDE)
        self._act()
        self._integrate()
        self._run(Phase.DETECT)
        self._run(Phase.RECORD)
        if self.ctx.profile is not None:
            self.ctx.profile.end_tick()

    @property
    def n_ticks(self) -> int:
        """Ticks of the whole run (duration / dt)."""
        return round(self.ctx.duration / self.ctx.dt)

    def start(self) -> None:
        """Set every component up (providers first); then ``step`` until ``n_ticks``, then ``stop``."""
        for c in self.setup_order:
            c.setup(self.ctx)

    def finish(self) -> dict[str, Any]:
        """Every component's metrics, merged (column owners checked)."""
        metrics: dict[str, Any] = {}
        owner: dict[str, str] = {}
        for c in self.ctx.components.values():
            merge_metrics(metrics, owner, c.finish(self.ctx), c.name)
        return metrics

    def close(self) -> None:
        """Close every component (a backend releases its library: libsumo allows one run per process)."""
        for c in self.ctx.components.values():
            c.close()

    def run(self) -> dict[str, Any]:
        """Set up, tick to the end, collect every component's metrics; always closes components."""
        t0 = time.perf_counter()
        try:
            self.start()
            if self.ctx.profile is not None:
                self.ctx.profile.begin(self.ctx.shard)
            for _ in range(self.n_ticks):
                self.step()
            if self.ctx.profile is not None:
                self.ctx.profile.end()
            metrics = self.finish()
        finally:
            self.close()
            self.wall_s = time.perf_counter() - t0
        return metrics
