"""corridor.scenario is a package (schema, files, messages, yaml_load, overrides, loader) whose public
names are all importable from corridor.scenario itself, as they were from the one module."""

from __future__ import annotations

import importlib

import corridor.scenario as scenario

MODULES = ("schema", "files", "messages", "yaml_load", "overrides", "loader")


def test_every_public_name_is_exported_from_the_package() -> None:
    for name in scenario.__all__:
        assert getattr(scenario, name) is not None, name
    for module in MODULES:  # every public function and class of a module is in __all__
        mod = importlib.import_module(f"corridor.scenario.{module}")
        own = [n for n, v in vars(mod).items() if not n.startswith("_") and getattr(v, "__module__", None) == mod.__name__]
        assert set(own) <= set(scenario.__all__), (module, sorted(set(own) - set(scenario.__all__)))


def test_the_users_imports_still_work(scenario_path) -> None:
    from corridor.scenario import Scenario, load, resolve_scenario

    sc, raw = load(scenario_path("merging"), ["duration=60", "warmup=0"])
    assert isinstance(sc, Scenario) and sc.duration == 60.0 and raw["name"] == "merging"
    assert resolve_scenario("merging") == scenario_path("merging")
