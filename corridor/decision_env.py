"""A decision-point Gymnasium environment: agents that come and go decide their mode switches.

The V2X merge's vehicles hold an automaton only while they are coordinated (``controller.automata``
gains and loses entries as they come and go), so no fixed set of agents exists to step in parallel.
The standard answer (parameter sharing, as in the multi-agent PPO literature, with a decision-point
view of the episode): **one policy shared by every vehicle**, and each environment step is **one
pending switch decision of one vehicle**.  The simulation runs until some vehicle's guard at a
boundary named in ``boundaries`` is evaluated inside the band where ``--method blrl`` would draw
(``corridor.modes.in_band`` with ``SwitchingParams(temperature, band)``; default blrl's first
temperature, so PPO faces the decisions blrl starts from, over the widest range blrl searches);
there it stops, returns that decision's observation and resumes with the action.  Elsewhere, and at
every other boundary, the switch is deterministic (theta0), as in blrl.  Within one controller tick
the decisions come in the controller's own order (its vehicles in order, each vehicle's guards in the
automaton's order): deterministic.  A guard whose discrete condition (``when``) fails cannot fire and
asks nothing.

- ``step(action)``: ``Discrete(2)``; 1 = the guard holds (the vehicle switches), 0 = it does not.
- Observation (``Box(OBS)``, normalised: lengths / 100 m, speeds / 30 m/s): the boundary's kind
  (one-hot over ``boundaries``), g at theta0 (the guard value), the guard's inputs
  (``state.features()``: distance, predecessor, virtual gap, its speed, age, length; zero-padded to
  ``STATE_FEATURES``), and highway-env's Kinematics of the vehicle and its ``n_nearest`` nearest
  vehicles (``[presence, x, y, vx, vy]``: its own speed, the others relative to it; zero rows when
  fewer exist) from the world snapshot the controller read.
- Reward: 0 until the run ends; then ``objective(row) - penalty x violated constraints`` (as
  ``run_scenario --learn``; ``penalty_kind="hinge"``, ``--penalty hinge``: each broken constraint
  counts 1 + how far the row is past it).  The episode *terminates* at the run's end (its fixed duration is part of
  the task, so PPO does not bootstrap past the only reward); ``info`` then holds the row's metrics, the
  seed, the ``draw.*`` values and ``decisions``; before, the vehicle, boundary, time and
  ``default_action`` (what theta0 decides: taking it at every step reproduces ``run_scenario``'s row).

How the simulation stops inside a controller tick: the run executes in a ``greenlet`` (the same OS
thread, so libsumo's one-simulation-per-process rule holds) and the automata's ``decider`` hook
(``corridor.modes.HybridAutomaton.decider``) switches back to ``step``; the controllers are not
changed.  A run with no decision at all returns its reward at the first step.

    import gymnasium, corridor.decision_env
    env = gymnasium.make("corridor/MergeDecisions-v0", sets=["duration=180", "warmup=60"])
    obs, info = env.reset(seed=0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from corridor.batch import draws_for
from corridor.errors import CorridorError
from corridor.modes import Boundary, HybridAutomaton, SwitchingParams, in_band
from corridor.objective import Expression, hinge_violations, value, violations
from corridor.run import ScratchRun, event_counts
from corridor.scenario import load
from corridor.snapshot import nearest_indices

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
MERGE_BOUNDARIES = ("merge_enter", "gap_accept", "gap_reject", "yield_enter", "yield_exit", "yield_hold", "yield_pass",
                    "open_ahead")  # open_ahead: off (dist_m 0, no band) unless the scenario sets it
STATE_FEATURES = 8  # the guard's inputs (state.features()), zero-padded
KINEMATICS = 5  # presence, x, y, vx, vy
LENGTH_M, SPEED_MPS = 100.0, 30.0  # normalisation scales
BOUND = 1.0e3  # the observation box (normalised units; far beyond any scenario)
T0 = 0.5  # [log units] blrl's first temperature (corridor.learn.T0): the band PPO decides in


@dataclass
class _Pending:
    """A decision the run waits for."""

    obs: np.ndarray
    info: dict[str, Any]


class DecisionEnv(gym.Env):
    """One pending boundary decision per step; one policy for every vehicle (see the module docstring)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, scenario: str | Path = "merging.yaml", controller: str = "merge", variant: str | None = "v2x_cps",
                 sets: list[str] | None = None, boundaries: tuple[str, ...] = MERGE_BOUNDARIES,
                 objective: str = "-delay_mean_s", constraints: tuple[str, ...] = ("collisions == 0",),
                 penalty: float = 1.0, temperature: float = T0, band: float = 4.0, n_nearest: int = 4,
                 penalty_kind: str = "count") -> None:
        self.path = Path(scenario) if Path(scenario).exists() else SCENARIOS / scenario
        self.sc, self.raw = load(self.path, sets)
        if variant is not None and variant not in self.sc.sweep:
            raise CorridorError(f"{self.path.name}: no variant {variant!r} (have {', '.join(self.sc.sweep)})")
        self.variant_overrides = dict(self.sc.sweep[variant]) if variant else {}
        if not boundaries:
            raise CorridorError("DecisionEnv: name at least one boundary to decide")
        if penalty_kind not in ("count", "hinge"):
            raise CorridorError(f"DecisionEnv: penalty_kind {penalty_kind!r}: one of count, hinge")
        self.penalty_kind = penalty_kind
        self.controller, self.boundaries, self.penalty, self.n_nearest = controller, tuple(boundaries), penalty, n_nearest
        self.switching = SwitchingParams(temperature=temperature, band=band)
        self.objective = Expression(objective, "objective")
        self.constraints = tuple(Expression(c, "constraint") for c in constraints)
        n = len(self.boundaries) + 1 + STATE_FEATURES + KINEMATICS * (1 + n_nearest)
        self._n = n
        self.observation_space = spaces.Box(-BOUND, BOUND, shape=(n,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self._run: ScratchRun | None = None
        self._glet: Any = None
        self._ended: dict[str, Any] | None = None

    # ---- the gymnasium interface -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        from greenlet import greenlet

        super().reset(seed=seed)
        self.close()
        run_seed = seed if seed is not None else int(self.np_random.integers(2**31 - 1))
        draws = (options or {}).get("draws")
        self.seed_, self.draws = run_seed, (draws_for(self.sc, run_seed) if draws is None else dict(draws))
        self._run = ScratchRun(self.path, self.raw, {**self.variant_overrides, **self.draws}, run_seed)
        self.decisions = 0
        self._glet = greenlet(self._simulate)
        got = self._glet.switch()
        if isinstance(got, _Pending):
            return got.obs, {"seed": run_seed, **got.info}
        self.close()
        self._ended = got  # no decision in the whole run: the first step returns its reward
        return np.zeros(self._n, np.float32), {"seed": run_seed}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._ended is not None:
            metrics, self._ended = self._ended, None
            return np.zeros(self._n, np.float32), self.reward(metrics), True, False, metrics
        if self._glet is None or self._glet.dead:
            raise CorridorError("DecisionEnv.step: call reset first (the run has ended)")
        got = self._glet.switch(bool(int(action)))
        if isinstance(got, _Pending):
            return got.obs, 0.0, False, False, got.info
        self.close()
        return np.zeros(self._n, np.float32), self.reward(got), True, False, got

    def close(self) -> None:
        """Abandon the run in progress (its greenlet unwinds) and close its simulation."""
        if self._glet is not None and not self._glet.dead:
            self._glet.throw()  # GreenletExit inside the run: it unwinds back here
        self._glet, self._ended = None, None
        if self._run is not None:
            self._run.close()
        self._run = None

    def reward(self, metrics: dict[str, Any]) -> float:
        v = value(self.objective, metrics)
        broken = (hinge_violations if self.penalty_kind == "hinge" else violations)(self.constraints, metrics)
        return (v if math.isfinite(v) else -self.penalty) - self.penalty * broken

    # ---- the run (inside the greenlet) -----------------------------------------------------------------
    def _simulate(self) -> dict[str, Any]:
        assert self._run is not None
        sim = self._run.sim
        sim.start()
        ctrl = sim.ctx.components.get(self.controller)
        if ctrl is None or not isinstance(getattr(ctrl, "automata", None), dict):
            raise CorridorError(f"DecisionEnv: controller {self.controller!r} has no automata to decide "
                                "(choose a variant whose controller has boundaries)")
        ctrl.automata = _Hooked(ctrl.automata, self._decide)  # type: ignore[attr-defined]
        for _ in range(sim.n_ticks):
            sim.step()
        return {**sim.finish(), **event_counts(sim.ctx), "seed": self.seed_, "decisions": self.decisions,
                **{f"draw.{k}": v for k, v in self.draws.items()}}

    def _decide(self, ha: HybridAutomaton, b: Boundary, t: float, g: float, x: Any) -> bool | None:
        """The automata's decider: inside the band of a decided boundary, ask the agent (switch to ``step``)."""
        if b.name not in self.boundaries or not in_band(b, x, g, self.switching):
            return None
        self.decisions += 1
        info = {"vehicle": ha.tag, "boundary": b.name, "t": t, "default_action": int(b.holds(g))}
        return bool(self._glet.parent.switch(_Pending(self._observe(ha.tag, b, g, x), info)))

    def _observe(self, vid: str, b: Boundary, g: float, x: Any) -> np.ndarray:
        kind = np.array([float(b.name == n) for n in self.boundaries])
        state = np.zeros(STATE_FEATURES)
        feats = list(x.features().items()) if hasattr(x, "features") else []
        for i, (name, v) in enumerate(feats[:STATE_FEATURES]):
            state[i] = _scaled(name, float(v))
        obs = np.concatenate([kind, [g / LENGTH_M], state, self._kinematics(vid).ravel()])
        out: np.ndarray = np.clip(np.nan_to_num(obs), -BOUND, BOUND).astype(np.float32)
        return out

    def _kinematics(self, vid: str) -> np.ndarray:
        """highway-env's Kinematics rows: the vehicle (its velocity) and its nearest vehicles, relative."""
        out = np.zeros((1 + self.n_nearest, KINEMATICS))
        assert self._run is not None
        s = self._run.sim.ctx.snapshot
        idx = s.index().get(vid) if s is not None else None
        if idx is None:
            return out
        pos, vel = np.asarray(s.position, float)[:, :2], np.asarray(s.velocity, float)[:, :2]
        out[0] = [1.0, 0.0, 0.0, *(vel[idx] / SPEED_MPS)]
        near = nearest_indices(pos, idx, self.n_nearest)
        out[1:1 + len(near)] = np.column_stack([np.ones(len(near)), (pos[near] - pos[idx]) / LENGTH_M,
                                                (vel[near] - vel[idx]) / SPEED_MPS])
        return out


def _scaled(name: str, v: float) -> float:
    """A feature in the observation's units: lengths / 100 m, speeds / 30 m/s, the rest as is."""
    if name.endswith("_mps"):
        return v / SPEED_MPS
    if name.endswith("_m"):
        return v / LENGTH_M
    return v


class _Hooked(dict):  # type: ignore[type-arg]
    """A controller's automata table whose every automaton (present or added later by ``table[vid] = ha``,
    as controllers add them) asks ``decider``."""

    def __init__(self, items: dict[str, HybridAutomaton], decider: Any) -> None:
        super().__init__(items)
        self.decider = decider
        for ha in self.values():
            ha.decider = decider

    def __setitem__(self, key: str, ha: HybridAutomaton) -> None:
        ha.decider = self.decider
        super().__setitem__(key, ha)


gym.register(id="corridor/MergeDecisions-v0", entry_point="corridor.decision_env:DecisionEnv",
             kwargs={"scenario": "merging.yaml"})
