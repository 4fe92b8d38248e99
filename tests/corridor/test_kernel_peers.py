"""Peers and periods are declared and resolved by the engine at build: needs by role or by a name
param, setup order (providers first), one-line errors, and the period sources with the scenario's
``period:`` override."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from corridor.engine import Component, Need, RunContext, Simulation


class Comp(Component):
    """A component whose needs, roles and period source are given per test (a fresh subclass)."""

    def __init__(self, name: str, log: list[str] | None = None, **params: Any) -> None:
        super().__init__(name)
        self.p = SimpleNamespace(**params)
        self.log = log if log is not None else []

    def setup(self, ctx: RunContext) -> None:
        self.log.append(self.name)


def kind(needs: dict[str, Need] | None = None, provides: set[str] = frozenset(), period_source: str | None = None,
         period: float = 0.1) -> type[Comp]:
    attrs = {"needs": needs or {}, "provides": frozenset(provides), "period_source": period_source,
             "period": period}
    return type("K", (Comp,), attrs)


def build(*comps: Component, dt: float = 0.1, duration: float = 1.0) -> Simulation:
    return Simulation(RunContext(run_seed=0, dt=dt, duration=duration), comps)


def one_line_error(*comps: Component, dt: float = 0.1) -> str:
    with pytest.raises(ValueError) as exc:
        build(*comps, dt=dt)
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


Road = kind(provides={"road"}, period_source="p.step_s")
Monitor = kind(needs={"road": Need(role="road", hint="add `road:` to the scenario")}, period_source="peer:road")


# ---------------------------------------------------------------------- peers
def test_a_need_by_role_is_set_before_setup() -> None:
    road, mon = Road("road", step_s=0.5), Monitor("mon")
    build(mon, road)
    assert mon.road is road


def test_a_missing_peer_is_a_one_line_error_with_the_hint() -> None:
    msg = one_line_error(Monitor("mon"))
    assert msg == "mon: need 'road' (role 'road'): no component provides it; add `road:` to the scenario"


def test_an_ambiguous_role_names_the_candidates() -> None:
    msg = one_line_error(Road("a", step_s=0.1), Road("b", step_s=0.1), Monitor("mon"))
    assert msg == "mon: need 'road' (role 'road') is ambiguous: candidates a, b"


def test_a_name_param_picks_one_of_several_providers() -> None:
    Ctl = kind(needs={"ego": Need(role="ego", name_at="p.ego")})
    Ego = kind(provides={"ego"})
    a, b, ctl = Ego("a"), Ego("b"), Ctl("ctl", ego="b")
    build(a, b, ctl)
    assert ctl.ego is b


def test_a_name_param_pointing_at_the_wrong_role_is_an_error() -> None:
    Ctl = kind(needs={"ego": Need(role="ego", name_at="p.ego")})
    msg = one_line_error(Road("road", step_s=0.1), kind(provides={"ego"})("car"), Ctl("ctl", ego="road"))
    assert msg == ("ctl: need 'ego' (role 'ego'): component 'road' (p.ego) does not provide it "
                   "(its roles: road); components with that role: car")


def test_a_name_param_naming_no_component_is_an_error_unless_optional() -> None:
    Ctl = kind(needs={"ego": Need(role="ego", name_at="p.ego")})
    msg = one_line_error(Ctl("ctl", ego="nobody"))
    assert msg == "ctl: need 'ego' (role 'ego'): no component named 'nobody' (p.ego); components with that role: none"
    Opt = kind(needs={"air": Need(role="air", name_at="p.backend", optional=True)})
    a, b = Opt("a", backend=None), Opt("b", backend="absent")
    build(a, b)
    assert a.air is None and b.air is None


def test_a_dependency_cycle_is_an_error() -> None:
    A = kind(needs={"b": Need(role="rb")}, provides={"ra"})
    B = kind(needs={"a": Need(role="ra")}, provides={"rb"})
    assert one_line_error(A("a"), B("b")) == "component needs form a cycle: a -> b -> a"


def test_setup_order_puts_providers_first_and_keeps_the_build_order_otherwise() -> None:
    log: list[str] = []
    Det = kind(provides={"det"})
    Ctl = kind(needs={"det": Need(role="det")})
    Kpi = kind(needs={"det": Need(role="det"), "road": Need(role="road")})
    comps = [Road("road", log, step_s=0.1), Ctl("ctl", log), Comp("other", log), Det("det", log), Kpi("kpi", log)]
    sim = build(*comps)
    sim.run()
    assert log == ["road", "det", "ctl", "other", "kpi"]
    assert [c.name for c in sim.setup_order] == log
    assert sim.provider("det") is comps[3]


# ---------------------------------------------------------------------- periods
def test_period_from_each_source() -> None:
    Dt = kind(period_source="dt")
    Run = kind(period_source="run")
    Param = kind(period_source="p.tick_s")
    Const = kind(period=0.3)
    road, mon = Road("road", step_s=0.5), Monitor("mon")
    comps = [road, mon, Dt("dt"), Run("run"), Param("param", tick_s=2.0), Const("const")]
    build(*comps, dt=0.1, duration=7.0)
    assert [c.period for c in comps] == [0.5, 0.5, 0.1, pytest.approx(7.0), 2.0, 0.3]


def test_the_scenario_period_overrides_the_source_and_a_peer_sees_it() -> None:
    road, mon, param = Road("road", step_s=0.5), Monitor("mon"), kind(period_source="p.tick_s")("param", tick_s=2.0)
    road.period_override, param.period_override = 0.2, 1.0
    build(mon, road, param)
    assert (road.period, mon.period, param.period) == (0.2, 0.2, 1.0)


def test_a_period_that_is_not_a_multiple_of_dt_is_an_error() -> None:
    msg = one_line_error(kind(period_source="p.tick_s")("ctl", tick_s=0.25), dt=0.1)
    assert msg == "ctl: period 0.25 s is not a multiple of dt 0.1 s"
    over = kind(period_source="dt")("mon")
    over.period_override = 0.15
    assert "mon: period 0.15 s is not a multiple of dt 0.1 s" == one_line_error(over, dt=0.1)


def test_a_peer_period_source_must_name_a_need() -> None:
    Bad = kind(period_source="peer:road")
    assert one_line_error(Bad("bad")) == "bad: period_source 'peer:road' names no need (needs: none)"


def test_the_packaged_components_declare_their_peers() -> None:
    """Every lookup of a peer goes through declared needs: no component scans ``ctx.components``."""
    from corridor.analysis.monitoring.ramp_kpis import RampKpis
    from corridor.analysis.monitoring.road import TrafficKpis
    from corridor.controllers.overtaking.components import OvertakingSumo
    from corridor.controllers.ramp_metering.components import RampControl
    from corridor.traffic.sumo.backend import SumoBackend
    from corridor.vehicles.ground.ego_bicycle import EgoBicycle

    assert "road" in SumoBackend.provides and "ego" in EgoBicycle.provides
    assert EgoBicycle.needs["sumo"].role == "road" and EgoBicycle.period_source == "peer:sumo"
    assert OvertakingSumo.needs["ego"] == Need(role="ego", name_at="p.ego")
    assert {n.role for n in RampKpis.needs.values()} == {"trips", "ramp_detectors"}
    assert RampControl.needs["det"].role == "ramp_detectors"
    assert TrafficKpis.needs["trips"].role == "trips"

