"""A Gymnasium environment in highway-env's conventions: a learning agent drives one ego vehicle.

The scenario runs as ``run_scenario`` runs it (its network, its calibrated drivers, its monitors), with
one more controller: an *ego agent* component (``agent_type``, e.g. ``merge_agent`` or
``overtaking_agent``; ``drop_controllers`` removes the scenario's own controller of that ego).  The
component picks or inserts the ego, turns the action it holds into commands through the scenario's
safety layer on every tick, and scores each decision.  The environment owns the episode:

- ``reset(seed=s)`` builds the run of seed ``s`` (the scenario's ``randomize`` draws for that seed and
  the variant's overrides), runs it until the ego is on the road and returns the first observation.
  libsumo allows one simulation per process: ``reset`` closes the previous run first.  The same seed
  gives the same observation and, for the same actions, the same trajectory.
- ``step(action)`` holds the action for ``decision_period_s`` (highway-env's policy period, 1 s).
- Observation: highway-env's *Kinematics* (``absolute=False``, ``normalize=True``): ``vehicles_count``
  rows ``[presence, x, y, vx, vy]`` in the scenario's ENU frame, clipped to [-1, 1] after dividing
  by ``features_range``; row 0 the ego (its x, y from the component's ``reference_xy``, e.g. the end
  of the acceleration lane; its vx, vy absolute), then the nearest other vehicles within the x and y
  ranges, relative to the ego, nearest first; zero rows when fewer are seen.
- Episode end: ``terminated`` when the ego collides (a ``collision`` event naming it: the collision
  monitor's oriented-box or SUMO's check) or the component says its goal is reached;
  ``truncated`` after ``max_episode_s`` or at the scenario's end.  ``info`` holds the component's
  per-step terms every step and, at the end, the run's results row (its metrics up to that moment,
  e.g. ``collisions``, ``hard_brakes``, ``delay_mean_s``; a metric without a value, NaN in the row, is
  None here) and the ``seed``.

The component's side (duck-typed, see ``corridor.controllers.merging.agent_components``): ``ego_id`` (the
vehicle id once it drives, else None), ``reference_xy`` [m], ``act(action)`` and
``outcome(collided) -> (reward, done, info)`` (done: the goal is reached or the ego left the road);
a component that drives several vehicles (``EgoParallelEnv``) takes an agent ``slot`` in both and
names their vehicles with ``vid_of(slot)``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Literal, Protocol, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from corridor.batch import draws_for
from corridor.engine import Simulation
from corridor.errors import CorridorError
from corridor.run import ScratchRun, event_counts
from corridor.scenario import load
from corridor.snapshot import WorldSnapshot

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
KINEMATICS = ("presence", "x", "y", "vx", "vy")
MAX_SPEED_MPS = 40.0  # highway-env's Vehicle.MAX_SPEED: its default ranges are multiples of it
DEFAULT_RANGES = {"x": 5.0 * MAX_SPEED_MPS, "y": 12.0, "vx": 2.0 * MAX_SPEED_MPS, "vy": 2.0 * MAX_SPEED_MPS}  # [m], [m/s]
AGENT = "agent"  # the controller name the ego agent component gets in the run


class EgoAgent(Protocol):
    """What an ego agent component offers the environment."""

    reference_xy: tuple[float, float]  # [m] ENU point the ego row's x, y are measured from

    @property
    def ego_id(self) -> str | None:
        """The vehicle the agent drives (None until it is on the road)."""

    def vid_of(self, slot: str) -> str | None:
        """The vehicle agent ``slot`` drives (None until it is on the road)."""

    def act(self, action: Any, slot: str = "ego") -> None:
        """Hold ``action`` from now on (it is applied every tick through the safety layer)."""

    def outcome(self, collided: bool, slot: str = "ego") -> tuple[float, bool, dict[str, Any]]:
        """The decision period's reward, whether the vehicle is done (goal or gone), per-step info."""


def kinematics(s: WorldSnapshot, ego_row: int, count: int, ranges: dict[str, float],
               reference_xy: tuple[float, float]) -> np.ndarray:
    """highway-env's Kinematics observation of ``ego_row`` (see the module docstring), float32."""
    pos, vel = np.asarray(s.position, float)[:, :2], np.asarray(s.velocity, float)[:, :2]
    scale = np.array([ranges["x"], ranges["y"], ranges["vx"], ranges["vy"]])
    out = np.zeros((count, len(KINEMATICS)))
    out[0] = np.concatenate([[1.0], (pos[ego_row] - np.asarray(reference_xy)) / scale[:2], vel[ego_row] / scale[2:]])
    rel = pos - pos[ego_row]
    seen = (np.abs(rel[:, 0]) <= ranges["x"]) & (np.abs(rel[:, 1]) <= ranges["y"])
    seen[ego_row] = False
    others = np.flatnonzero(seen)
    near = others[np.argsort(np.hypot(rel[others, 0], rel[others, 1]), kind="stable")[: count - 1]]
    if near.size:
        out[1:1 + near.size, 0] = 1.0
        out[1:1 + near.size, 1:] = np.column_stack([rel[near], vel[near] - vel[ego_row]]) / scale
    return np.clip(out, -1.0, 1.0).astype(np.float32)


def _no_nan(value: Any) -> Any:
    """A row's NaN (a metric without a value, e.g. ``first_collision_s`` of a run without one) as None:
    NaN != NaN, so Gymnasium's checker would take two identical rows for different ones."""
    return None if isinstance(value, float) and np.isnan(value) else value


class EgoEnv(gym.Env):
    """One ego vehicle of a scenario driven by the agent (see the module docstring)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, scenario: str | Path, agent_type: str, variant: str | None = None,
                 sets: list[str] | None = None, agent_params: dict[str, Any] | None = None,
                 drop_controllers: tuple[str, ...] = (), action_type: Literal["discrete", "continuous"] = "discrete",
                 vehicles_count: int = 5, features_range: dict[str, float] | None = None,
                 decision_period_s: float = 1.0, max_episode_s: float = 60.0) -> None:
        if action_type not in ("discrete", "continuous"):
            raise CorridorError(f"action_type {action_type!r}: must be 'discrete' or 'continuous'")
        if vehicles_count < 1:
            raise CorridorError(f"vehicles_count {vehicles_count}: must be >= 1 (row 0 is the ego)")
        self.path = Path(scenario) if Path(scenario).exists() else SCENARIOS / scenario
        self.sc, raw = load(self.path, sets)
        if variant is not None and variant not in self.sc.sweep:
            raise CorridorError(f"{self.path.name}: no variant {variant!r} (have {', '.join(self.sc.sweep)})")
        self.raw = copy.deepcopy(raw)
        for name in drop_controllers:
            self.raw.get("controllers", {}).pop(name, None)
        self.overrides = {**(dict(self.sc.sweep[variant]) if variant else {}),
                          f"controllers.{AGENT}": {"type": agent_type,
                                                   "params": {**(agent_params or {}), "action": action_type}}}
        self.ranges = {**DEFAULT_RANGES, **(features_range or {})}
        self.count, self.decision_period_s, self.max_episode_s = vehicles_count, decision_period_s, max_episode_s
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(vehicles_count, len(KINEMATICS)), dtype=np.float32)
        self.action_space: spaces.Space[Any] = (spaces.Discrete(5) if action_type == "discrete"
                                                else spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32))
        self.sim: Simulation | None = None
        self._run: ScratchRun | None = None

    # ------------------------------------------------------------------ the run
    def _start(self, seed: int) -> None:
        self._close_run()
        self.seed_, self.draws = seed, draws_for(self.sc, seed)
        self._run = ScratchRun(self.path, self.raw, {**self.overrides, **self.draws}, seed)
        self.sim, sc = self._run.sim, self._run.sc
        self.sim.start()
        comp = self.sim.ctx.components[AGENT]
        if not all(hasattr(comp, a) for a in ("ego_id", "act", "outcome")):
            raise CorridorError(f"agent_type: {type(comp).__name__} is not an ego agent (ego_id, act, outcome)")
        self.agent = cast(EgoAgent, comp)
        self.ticks_per_decision = max(1, round(self.decision_period_s / sc.dt))
        self._events_seen = 0
        while self.agent.ego_id is None or self._ego_row() is None:  # traffic builds up until the ego drives
            if self.sim.ctx.tick >= self.sim.n_ticks:
                raise CorridorError(f"{self.path.name}: the ego never entered the road within duration={self.sc.duration}")
            self.sim.step()
        self.end_tick = min(self.sim.n_ticks, self.sim.ctx.tick + round(self.max_episode_s / sc.dt))

    def _ego_row(self) -> int | None:
        assert self.sim is not None
        ego = self.agent.ego_id
        return None if ego is None else self.sim.ctx.snapshot.index().get(ego)

    def _new_collisions(self) -> set[str]:
        """The entities named by ``collision`` events since the last look."""
        assert self.sim is not None
        events = self.sim.ctx.events.events
        new, self._events_seen = events[self._events_seen:], len(events)
        return {str(e.data.get(k)) for e in new if e.kind == "collision" for k in ("a", "b")}

    def _observe(self, vid: str | None = None) -> np.ndarray:
        """The Kinematics observation of ``vid`` (default: the ego)."""
        vid = self.agent.ego_id if vid is None else vid
        row = None if self.sim is None or vid is None else self.sim.ctx.snapshot.index().get(vid)
        if row is None:  # the vehicle left the network (or the run is closed)
            return np.zeros((self.count, len(KINEMATICS)), np.float32)
        assert self.sim is not None
        return kinematics(self.sim.ctx.snapshot, row, self.count, self.ranges, self.agent.reference_xy)

    def _row_info(self) -> dict[str, Any]:
        """The run's results row so far (NaN as None), its seed and draws."""
        assert self.sim is not None
        row = {**self.sim.finish(), **event_counts(self.sim.ctx)}
        return {**{k: _no_nan(v) for k, v in row.items()}, "seed": self.seed_,
                **{f"draw.{k}": v for k, v in self.draws.items()}}

    def _close_run(self) -> None:
        if self._run is not None:
            self._run.close()
        self.sim = self._run = None

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        run_seed = seed if seed is not None else int(self.np_random.integers(2**31 - 1))
        self._start(run_seed)
        return self._observe(), {"seed": run_seed, "ego": self.agent.ego_id}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.sim is None:
            raise CorridorError("step() after the episode ended: call reset() first")
        self.agent.act(action)
        collided = False
        for _ in range(self.ticks_per_decision):
            if self.sim.ctx.tick >= self.end_tick:
                break
            self.sim.step()
            collided = self.agent.ego_id in self._new_collisions()
            if collided or self._ego_row() is None:
                break
        reward, done, info = self.agent.outcome(collided)
        terminated = collided or done
        truncated = not terminated and self.sim.ctx.tick >= self.end_tick
        obs = self._observe()
        if terminated or truncated:
            info = {**info, **self._row_info()}
            self._close_run()
        return obs, float(reward), terminated, truncated, info

    def close(self) -> None:
        self._close_run()


class EgoParallelEnv(ParallelEnv):  # type: ignore[misc]  # pettingzoo has no type information
    """PettingZoo ``ParallelEnv``: ``n_agents`` vehicles driven by agents, each as ``EgoEnv``'s ego.

    The agent component must drive several vehicles (``merge_agent`` with ``agents: N``: the first N
    connected vehicles departing from ``ego_depart_s`` on; agent ``cv_k`` drives the k-th).  An agent
    joins ``agents`` when its vehicle departs and leaves it when it is done (goal, collision: each
    agent's own reward and termination as in ``EgoEnv``) or at truncation; the run closes when no
    agent is left.  ``possible_agents`` are the N slots; a slot whose vehicle has not departed before
    the end never appears.  At the end every agent's ``info`` holds the run's row.
    """

    metadata: dict[str, Any] = {"render_modes": [], "name": "corridor_ego_parallel_v0"}

    def __init__(self, n_agents: int = 4, **kwargs: Any) -> None:
        if n_agents < 2:
            raise CorridorError(f"n_agents {n_agents}: a parallel environment needs >= 2 (one agent: EgoEnv)")
        params = {**kwargs.pop("agent_params", {}), "agents": n_agents}
        self.core = EgoEnv(agent_params=params, **kwargs)
        self.possible_agents = [f"cv_{k}" for k in range(n_agents)]
        self.agents: list[str] = []
        self._rng = np.random.default_rng()  # run seeds of resets without a seed (until one is given)
        self._obs_space, self._act_space = self.core.observation_space, self.core.action_space

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._act_space

    def _departed(self) -> list[str]:
        """Slots whose vehicle is on the road and that have not finished."""
        return [a for a in self.possible_agents if a not in self._finished
                and (vid := self.core.agent.vid_of(a)) is not None and self.core.sim is not None
                and vid in self.core.sim.ctx.snapshot.index()]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        if seed is not None:  # later resets without a seed draw their run seeds from this one
            self._rng = np.random.default_rng(seed)
        run_seed = seed if seed is not None else int(self._rng.integers(2**31 - 1))
        self.core._start(run_seed)  # runs until the first agent's vehicle came near
        self._finished: set[str] = set()
        self.agents = self._departed()
        return {a: self.core._observe(self.core.agent.vid_of(a)) for a in self.agents}, \
            {a: {"seed": run_seed, "vid": self.core.agent.vid_of(a)} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], dict[str, float], dict[str, bool],
                                                     dict[str, bool], dict[str, Any]]:
        core = self.core
        if core.sim is None:
            raise CorridorError("step() after the episode ended: call reset() first")
        for a, u in actions.items():
            if a in self.agents:
                core.agent.act(u, a)
        hits: set[str] = set()
        for _ in range(core.ticks_per_decision):
            if core.sim.ctx.tick >= core.end_tick:
                break
            core.sim.step()
            hits |= core._new_collisions()
        obs, rew, term, trunc, info = {}, {}, {}, {}, {}
        ended = core.sim.ctx.tick >= core.end_tick
        for a in self.agents:
            vid = core.agent.vid_of(a)
            r, done, info[a] = core.agent.outcome(vid in hits, a)
            obs[a], rew[a] = core._observe(vid), r
            term[a] = vid in hits or done
            trunc[a] = ended and not term[a]
        for a in self._departed():  # vehicles that departed during this period join
            if a not in obs:
                vid = core.agent.vid_of(a)
                obs[a], rew[a], term[a], trunc[a], info[a] = core._observe(vid), 0.0, False, ended, {"vid": vid}
        self._finished |= {a for a in obs if term[a] or trunc[a]}
        self.agents = [a for a in obs if not (term[a] or trunc[a])]
        if not self.agents:
            row = core._row_info()
            info = {a: {**i, **row} for a, i in info.items()}
            core._close_run()
        return obs, rew, term, trunc, info

    def close(self) -> None:
        self.core.close()
