"""Gymnasium and PettingZoo environments over corridor scenarios: an agent decides a mode switch.

A controller whose agents run a ``HybridAutomaton`` (``controller.automata``: agent id -> automaton,
e.g. the UAVs of ``uav_encounter``) can hand one switch to a learning agent: the pair of boundaries
``switch = (enter, exit)`` (default ``("avoid_enter", "avoid_exit")``) is then decided by the action
instead of by the sign of g.  Everything else (the method inside each mode, the link, JSBSim, the
monitors) is the scenario as ``run_scenario`` runs it.

- ``reset(seed=s)`` builds the run of seed ``s`` (the scenario's ``randomize`` draws for that seed,
  or ``options={"draws": {...}}``, and the variant's overrides), sets it up and runs its first controller period (decided by the
  boundaries, so that the world snapshot exists).  The same seed
  gives the same observation and, for the same actions, the same trajectory.
- ``step(action)``: ``Discrete(2)``; 1 = the enter boundary holds and the exit one does not (switch
  to / stay in the avoiding mode), 0 = the reverse.  The run then advances one controller period.
- Observation (highway-env's *Kinematics*, absolute for the agent, relative for the others):
  ``Box((1 + n_nearest, 7))`` rows ``[presence, x, y, z, vx, vy, vz]`` [m, m/s] in the scenario's
  ENU frame; row 0 the agent itself, then the ``n_nearest`` nearest other entities (ground truth
  from the world snapshot, relative to the agent), zero rows when fewer exist.
- Reward: 0 until the run ends; at the end ``objective(row) - penalty x violations(row)`` on the
  run's results row (the same expressions as ``run_scenario --learn``; ``penalty_kind="hinge"``, as
  ``--penalty hinge``: each broken constraint costs 1 + how far the row is past its bound).  The episode ends by
  truncation at the scenario's duration; ``info`` then holds the row's metrics, the run's ``seed`` and its ``draw.*`` values.

libsumo allows one simulation per process: ``reset`` closes the previous run before building the
next, and ``close`` closes the current one.

    import gymnasium, corridor.envs
    env = gymnasium.make("corridor/UavEncounter-v0", sets=["duration=30"])
    obs, info = env.reset(seed=0)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from corridor.batch import draws_for
from corridor.ego_env import EgoParallelEnv
from corridor.engine import Simulation
from corridor.errors import CorridorError
from corridor.objective import Expression, hinge_violations, value, violations
from corridor.run import ScratchRun, event_counts
from corridor.scenario import load
from corridor.snapshot import nearest_indices

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
FEATURES = 7  # presence, x, y, z, vx, vy, vz
BOUND = 1.0e5  # [m], [m/s] observation box (far beyond any scenario)


class _Episode:
    """One run of a scenario stepped decision by decision (shared by both environments)."""

    def __init__(self, scenario: str | Path, controller: str, variant: str | None, sets: list[str] | None,
                 switch: tuple[str, str], objective: str, constraints: tuple[str, ...], penalty: float,
                 n_nearest: int, penalty_kind: str = "count") -> None:
        self.path = Path(scenario) if Path(scenario).exists() else SCENARIOS / scenario
        self.sc, self.raw = load(self.path, sets)
        if variant is not None and variant not in self.sc.sweep:
            raise CorridorError(f"{self.path.name}: no variant {variant!r} (have {', '.join(self.sc.sweep)})")
        self.variant_overrides = dict(self.sc.sweep[variant]) if variant else {}
        if controller not in self.sc.controllers:
            raise CorridorError(f"{self.path.name}: no controller {controller!r}")
        if penalty_kind not in ("count", "hinge"):
            raise CorridorError(f"penalty_kind {penalty_kind!r}: one of count, hinge")
        self.controller, self.switch, self.penalty, self.n_nearest = controller, switch, penalty, n_nearest
        self.penalty_kind = penalty_kind
        self.objective = Expression(objective, "objective")
        self.constraints = tuple(Expression(c, "constraint") for c in constraints)
        self.sim: Simulation | None = None
        self._run: ScratchRun | None = None
        self.agents: list[str] = []

    def start(self, seed: int, draws: dict[str, Any] | None = None) -> None:
        """Build and set up the run of ``seed``; ``draws``: the randomize values (default: the seed's)."""
        self.close()
        self.seed = seed
        self.draws = draws_for(self.sc, seed) if draws is None else dict(draws)
        overrides = {**self.variant_overrides, **self.draws}
        self._run = ScratchRun(self.path, self.raw, overrides, seed)
        self.sim, sc = self._run.sim, self._run.sc
        self.sim.start()
        self.ctrl = self.sim.ctx.components[self.controller]
        automata: dict[str, Any] | None = getattr(self.ctrl, "automata", None)
        if not automata:
            raise CorridorError(f"controller {self.controller!r} ({type(self.ctrl).__name__}) has no agents with "
                                "modes to decide (choose a variant whose controller has boundaries)")
        self.agents = sorted(automata)
        self.automata = automata
        for ha in automata.values():
            if not set(self.switch) <= set(ha.boundaries):
                raise CorridorError(f"switch {self.switch}: boundaries of {ha.name} are {sorted(ha.boundaries)}")
        self.ticks_per_decision = max(1, round(self.ctrl.period / sc.dt))  # resolved at build
        self.tick = 0
        self.advance()  # the first period (the boundaries decide it): the snapshot exists from here on

    def decide(self, actions: dict[str, int]) -> None:
        enter, leave = self.switch
        for agent, a in actions.items():
            self.automata[agent].decided = {enter: bool(a), leave: not bool(a)}

    def advance(self) -> tuple[bool, dict[str, Any]]:
        """One decision period; (ended, the row's metrics when it ended)."""
        assert self.sim is not None
        for _ in range(self.ticks_per_decision):
            if self.tick >= self.sim.n_ticks:
                break
            self.sim.step()
            self.tick += 1
        if self.tick < self.sim.n_ticks:
            return False, {}
        metrics = {**self.sim.finish(), **event_counts(self.sim.ctx), "seed": self.seed,
                   **{f"draw.{k}": v for k, v in self.draws.items()}}
        self.close()
        return True, metrics

    def reward(self, metrics: dict[str, Any]) -> float:
        v = value(self.objective, metrics)
        broken = (hinge_violations if self.penalty_kind == "hinge" else violations)(self.constraints, metrics)
        return (v if np.isfinite(v) else -self.penalty) - self.penalty * broken

    def observe(self, agent: str) -> np.ndarray:
        out = np.zeros((1 + self.n_nearest, FEATURES), np.float32)
        if self.sim is None:
            return out
        s = self.sim.ctx.snapshot
        idx = s.index().get(agent)
        if idx is None:
            return out
        pos, vel = np.asarray(s.position, float), np.asarray(s.velocity, float)
        out[0] = np.concatenate([[1.0], pos[idx], vel[idx]])
        near = nearest_indices(pos, idx, self.n_nearest)
        if near.size:
            rows = np.column_stack([np.ones(len(near)), pos[near] - pos[idx], vel[near] - vel[idx]])
            out[1:1 + len(near)] = rows
        return np.clip(out, -BOUND, BOUND)

    def close(self) -> None:
        if self._run is not None:
            self._run.close()
        self.sim = self._run = None


def _observation_space(n_nearest: int) -> spaces.Box:
    return spaces.Box(-BOUND, BOUND, shape=(1 + n_nearest, FEATURES), dtype=np.float32)


class CorridorEnv(gym.Env):
    """One agent of a scenario decides its mode switch; the others keep their boundaries."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, scenario: str | Path = "uav_encounter.yaml", controller: str = "avoid",
                 variant: str | None = "potential_field", agent: str | None = None, sets: list[str] | None = None,
                 switch: tuple[str, str] = ("avoid_enter", "avoid_exit"), objective: str = "-path_ratio_max",
                 constraints: tuple[str, ...] = ("nmac == 0", "collisions == 0"), penalty: float = 10.0,
                 n_nearest: int = 3, penalty_kind: str = "count") -> None:
        self.episode = _Episode(scenario, controller, variant, sets, switch, objective, constraints, penalty, n_nearest,
                                penalty_kind)
        self.agent = agent
        self.observation_space = _observation_space(n_nearest)
        self.action_space = spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        run_seed = seed if seed is not None else int(self.np_random.integers(2**31 - 1))
        self.episode.start(run_seed, (options or {}).get("draws"))
        agent = self.agent or self.episode.agents[0]
        if agent not in self.episode.agents:
            raise CorridorError(f"agent {agent!r}: the controller's agents are {self.episode.agents}")
        self._agent = agent
        return self.episode.observe(agent), {"seed": run_seed, "agent": agent}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.episode.decide({self._agent: int(action)})
        obs = self.episode.observe(self._agent)
        ended, metrics = self.episode.advance()
        if not ended:
            obs = self.episode.observe(self._agent)
        return obs, self.episode.reward(metrics) if ended else 0.0, False, ended, metrics

    def close(self) -> None:
        self.episode.close()


def parallel_env(**kwargs: Any) -> Any:
    """A PettingZoo ``ParallelEnv``: every agent of the controller decides its own switch."""
    return CorridorParallelEnv(**kwargs)


class CorridorParallelEnv(ParallelEnv):  # type: ignore[misc]  # pettingzoo has no type information
    """PettingZoo parallel API over the same episodes; all agents share the run's terminal reward."""

    metadata: dict[str, Any] = {"render_modes": [], "name": "corridor_parallel_v0"}

    def __init__(self, scenario: str | Path = "uav_encounter.yaml", controller: str = "avoid",
                 variant: str | None = "potential_field", sets: list[str] | None = None,
                 switch: tuple[str, str] = ("avoid_enter", "avoid_exit"), objective: str = "-path_ratio_max",
                 constraints: tuple[str, ...] = ("nmac == 0", "collisions == 0"), penalty: float = 10.0,
                 n_nearest: int = 3, penalty_kind: str = "count") -> None:
        self.episode = _Episode(scenario, controller, variant, sets, switch, objective, constraints, penalty, n_nearest,
                                penalty_kind)
        self._obs_space, self._act_space = _observation_space(n_nearest), spaces.Discrete(2)  # one object each
        self.episode.start(0)  # the agents' names are known once a run is built
        self.possible_agents = list(self.episode.agents)
        self.episode.close()
        self.agents: list[str] = []

    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._act_space

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        run_seed = seed if seed is not None else int(np.random.default_rng().integers(2**31 - 1))
        self.episode.start(run_seed)
        self.agents = list(self.possible_agents)
        return {a: self.episode.observe(a) for a in self.agents}, {a: {"seed": run_seed} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, Any]]:
        self.episode.decide({a: int(u) for a, u in actions.items() if a in self.agents})
        ended, metrics = self.episode.advance()
        obs = {a: self.episode.observe(a) for a in self.agents}
        r = self.episode.reward(metrics) if ended else 0.0
        out = (obs, {a: r for a in self.agents}, {a: False for a in self.agents},
               {a: ended for a in self.agents}, {a: dict(metrics) for a in self.agents})
        if ended:
            self.agents = []
        return out

    def close(self) -> None:
        self.episode.close()


gym.register(id="corridor/UavEncounter-v0", entry_point="corridor.envs:CorridorEnv",
             kwargs={"scenario": "uav_encounter.yaml"})
# highway-env's conventions (corridor.ego_env): an agent drives one ego vehicle
MERGE = {"scenario": "merging.yaml", "variant": "human", "agent_type": "merge_agent",
         "features_range": {"y": 40.0}}  # [m] the ramp meets the mainline at an angle
gym.register(id="corridor/Merge-v0", entry_point="corridor.ego_env:EgoEnv", kwargs=MERGE)
gym.register(id="corridor/Overtaking-v0", entry_point="corridor.ego_env:EgoEnv",
             kwargs={"scenario": "overtaking.yaml", "variant": "event", "agent_type": "overtaking_agent",
                     "drop_controllers": ("overtaking",), "max_episode_s": 45.0})


def merge_parallel_env(n_agents: int = 4, **kwargs: Any) -> EgoParallelEnv:
    """PettingZoo ``ParallelEnv`` of the merge: the first ``n_agents`` connected vehicles departing from
    ``agent_params["ego_depart_s"]`` (60 s) on are agents ``cv_0`` ... (``corridor.ego_env.EgoParallelEnv``)."""
    return EgoParallelEnv(n_agents=n_agents, **{**MERGE, **kwargs})

from corridor import decision_env as _decision_env  # noqa: E402,F401  (registers corridor/MergeDecisions-v0)
