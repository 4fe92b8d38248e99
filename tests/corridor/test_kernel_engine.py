"""Engine: multi-rate scheduling, the tick pipeline, per-subsystem randomness, modes as events."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.engine import Component, Controller, Phase, RunContext, Simulation
from corridor.events import EventLog
from corridor.modes import HybridAutomaton, Transition
from corridor.null_backend import NullBackend, SetVelocity


class Probe(Component):
    def __init__(self, name: str, phase: Phase, period: float, log: list) -> None:
        super().__init__(name)
        self.phase, self.period, self.log = phase, period, log

    def tick(self, ctx: RunContext) -> None:
        self.log.append((ctx.tick, self.name))


def make(duration: float = 1.0, dt: float = 0.1, comps=()) -> Simulation:
    return Simulation(RunContext(run_seed=1, dt=dt, duration=duration), comps)


def test_closed_form_constant_velocity():
    b = NullBackend("b", ["a"], np.zeros((1, 3)), np.array([[20.0, 0, 0]]))
    sim = make(2.0, 0.1, [b])
    sim.run()
    assert sim.ctx.t == pytest.approx(2.0)
    assert sim.ctx.snapshot.position[0, 0] == pytest.approx(40.0)  # 20 m/s for 2 s is 40 m


def test_multi_rate_components_run_when_due():
    log: list = []
    fast = Probe("fast", Phase.DECIDE, 0.1, log)
    slow = Probe("slow", Phase.DECIDE, 0.5, log)
    make(2.0, 0.1, [fast, slow]).run()
    assert sum(1 for _, n in log if n == "fast") == 20
    assert [k for k, n in log if n == "slow"] == [0, 5, 10, 15]


def test_pipeline_order_within_a_tick():
    log: list = []
    comps = [Probe(p.name, p, 0.1, log) for p in reversed(list(Phase)) if p != Phase.ACT]
    make(0.1, 0.1, comps).run()
    assert [n for _, n in log] == ["SENSE", "COMMUNICATE", "DECIDE", "INTEGRATE", "DETECT", "RECORD"]


def test_period_must_be_multiple_of_dt():
    with pytest.raises(ValueError, match="not a multiple"):
        make(1.0, 0.1, [Probe("p", Phase.SENSE, 0.25, [])])


def test_commands_reach_backend_in_act_phase():
    class Stop(Controller):
        def step(self, obs):
            return [SetVelocity("a", (0.0, 0.0, 0.0))] if obs.t >= 1.0 else []

    b = NullBackend("b", ["a"], np.zeros((1, 3)), np.array([[10.0, 0, 0]]))
    sim = make(3.0, 0.1, [b, Stop("stop")])
    sim.run()
    assert sim.ctx.snapshot.position[0, 0] == pytest.approx(10.0, abs=1e-9)


def test_rng_streams_depend_on_name_and_seed_only():
    a = RunContext(run_seed=5, dt=0.1, duration=1).rng("x").random(4)
    b = RunContext(run_seed=5, dt=0.1, duration=1).rng("x").random(4)
    c = RunContext(run_seed=5, dt=0.1, duration=1).rng("y").random(4)
    d = RunContext(run_seed=6, dt=0.1, duration=1).rng("x").random(4)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c) and not np.array_equal(a, d)


def test_mode_transitions_are_events():
    ev = EventLog()
    ha = HybridAutomaton("ego", ["follow", "pass"], "follow", [
        Transition("follow", "pass", guard=lambda x: x > 5, label="gap found"),
        Transition("pass", "follow", guard=lambda x: x < 0, label="done"),
    ])
    modes = [ha.update(t, x, ev)[0] for t, x in enumerate([1, 6, 7, -1, 2])]
    assert modes == ["follow", "pass", "pass", "follow", "follow"]
    assert [e.message for e in ev.of_kind("mode")] == ["follow -> pass: gap found", "pass -> follow: done"]
    with pytest.raises(ValueError):
        HybridAutomaton("bad", ["a"], "a", [Transition("a", "b", guard=bool)])


def test_duplicate_metric_column_is_an_error_naming_both():
    class Kpi(Component):
        def __init__(self, name: str, value: float) -> None:
            super().__init__(name)
            self.value = value

        def finish(self, ctx):
            return {"tts_vh": self.value, f"own_{self.name}": 1}

    sim = make(0.2, 0.1, [Kpi("traffic", 1.0), Kpi("ramp", 2.0)])
    with pytest.raises(ValueError, match="'tts_vh' is written by both 'traffic' and 'ramp'") as err:
        sim.run()
    assert "\n" not in str(err.value)
    assert make(0.2, 0.1, [Kpi("traffic", 1.0)]).run() == {"tts_vh": 1.0, "own_traffic": 1}


def test_declared_metric_columns_collide_at_build_and_the_kpi_prefix_namespaces_them():
    from types import SimpleNamespace

    from corridor.analysis.monitoring.ramp_kpis import RampKpis
    from corridor.analysis.monitoring.road import TrafficKpis

    sc = SimpleNamespace(warmup=0.0, dt=0.1)
    traffic = TrafficKpis("traffic", TrafficKpis.Params(), sc)
    ramp = RampKpis("ramp", RampKpis.Params(), sc)
    assert traffic.metric_columns() & ramp.metric_columns() == {"tts_vh", "delay_mean_s", "delay_total_vh",
                                                                 "throughput_vph"}
    with pytest.raises(ValueError, match="'delay_mean_s' is declared by both 'traffic' and 'ramp'"):
        Simulation(RunContext(run_seed=0, dt=0.1, duration=1.0), [traffic, ramp])
    ramp = RampKpis("ramp", RampKpis.Params(prefix="ramp."), sc)
    assert ramp.metric_columns() == {"ramp.tts_vh", "ramp.delay_mean_s", "ramp.delay_total_vh", "ramp.throughput_vph"}
    assert not traffic.metric_columns() & ramp.metric_columns()
