"""Every entry-point group is read by one mechanism (corridor.entrypoints): a name declared twice with
different targets is a one-line error in each group, the same target twice is not, an unknown name
lists the known ones.  The duplicates are real installed metadata: a ``.dist-info`` in a temporary
folder on PYTHONPATH, read by importlib.metadata in a subprocess, as a second installed package's."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from corridor.entrypoints import DuplicateEntry, Registry, UnknownName
from corridor.errors import CorridorError

# one of corridor's own names per group, declared again by the "other" package
OWN = {
    "corridor.components": "controller.ramp_alinea",
    "corridor.reports": "html",
    "corridor.report_sections": "series",
    "corridor.estimators": "ce",
    "corridor.networks": "beltway",
}

# each group's public lookup, as corridor's code calls it
PROBES = """
import json, sys
out = {}
def probe(group, fn):
    try:
        fn()
        out[group] = None
    except Exception as exc:
        out[group] = [type(exc).__name__, isinstance(exc, CorridorError), str(exc)]
from corridor.errors import CorridorError
from corridor.registry import CONTROLLERS
from corridor.reports import write_reports
from corridor.analysis.report import write_batch_report
from corridor.estimate import method_class
from corridor.traffic.networks.registry import params_model
groups = set(sys.argv[2].split(","))
probes = {
    "corridor.components": lambda: CONTROLLERS.get("ramp_alinea"),
    "corridor.reports": lambda: write_reports(None, None, sys.argv[1], None),
    "corridor.report_sections": lambda: write_batch_report(None, None, sys.argv[1], None),
    "corridor.estimators": lambda: method_class("ce"),
    "corridor.networks": lambda: params_model("beltway"),
}
for group, fn in probes.items():
    if group in groups:
        probe(group, fn)
print(json.dumps(out))
"""


def install(site: Path, entries: dict[str, dict[str, str]]) -> None:
    """A second installed distribution declaring ``entries`` (group -> {name: target})."""
    info = site / "corridor_other-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: corridor-other\nVersion: 1.0\n")
    lines = []
    for group, names in entries.items():
        lines += [f"[{group}]", *(f"{n} = {v}" for n, v in names.items()), ""]
    (info / "entry_points.txt").write_text("\n".join(lines))


def probe(site: Path, groups: list[str], tmp: Path) -> dict[str, list | None]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-c", PROBES, str(tmp), ",".join(groups)], env=env, cwd=tmp,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_a_name_declared_twice_differently_is_an_error_in_every_group(tmp_path: Path) -> None:
    install(tmp_path / "site", {g: {n: "corridor_other.elsewhere:Thing"} for g, n in OWN.items()})
    out = probe(tmp_path / "site", list(OWN), tmp_path)
    for group, name in OWN.items():
        kind, is_corridor_error, message = out[group]
        assert kind == "DuplicateEntry" and is_corridor_error, (group, out[group])
        assert message.startswith(f"{group}: '{name}' is declared twice (") and "\n" not in message, message
        assert "corridor_other.elsewhere:Thing" in message


def test_the_same_target_declared_twice_is_no_error(tmp_path: Path) -> None:
    """A distribution found twice (an editable install and a path) declares the same targets."""
    same = {"corridor.components": {"controller.ramp_alinea":
                                    "corridor.controllers.ramp_metering.components:RampAlinea"},
            "corridor.estimators": {"ce": "corridor.analysis.rare.ce:CrossEntropy"},
            "corridor.networks": {"beltway": "corridor.traffic.networks.beltway"}}
    install(tmp_path / "site", same)
    assert probe(tmp_path / "site", list(same), tmp_path) == {g: None for g in same}


def test_the_command_line_prints_a_duplicate_as_one_line(tmp_path: Path) -> None:
    install(tmp_path / "site", {"corridor.components": {"monitor.collisions": "corridor_other.m:Mine"}})
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site")}
    proc = subprocess.run([sys.executable, "-m", "corridor.cli", "merging", "--out", str(tmp_path / "o")],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines() == [
        "run_scenario: corridor.components: 'monitor.collisions' is declared twice "
        "(corridor.analysis.monitoring.collisions:CollisionMonitor and corridor_other.m:Mine); "
        "uninstall one of the packages that declare it"]
    assert not (tmp_path / "o").exists()


def test_an_unknown_name_lists_the_known_ones_and_imports_nothing() -> None:
    reg = Registry("widget", "corridor.no_such_group")
    reg.register("b", "corridor_no_such_module:B")  # never imported: only named
    reg.register("a", "json:dumps")
    with pytest.raises(UnknownName) as info:
        reg.get("c")
    assert str(info.value) == "unknown widget 'c'; known: a, b"
    assert isinstance(info.value, KeyError) and isinstance(info.value, CorridorError)
    assert reg.get("a") is json.dumps
    assert reg.names() == ["a", "b"]


def test_registering_a_known_name_elsewhere_is_refused() -> None:
    reg = Registry("widget", "corridor.no_such_group")
    reg.register("a", "json:dumps")
    reg.register("a", "json:dumps")  # the same target again: fine
    with pytest.raises(DuplicateEntry, match=r"widget 'a' is already registered \(json:dumps\)"):
        reg.register("a", "json:loads")


def test_a_module_target_is_the_module() -> None:
    reg = Registry("network kind", "corridor.networks")
    assert "beltway" in reg and {"beltway", "highway_onramp"} <= set(reg.names())
    assert reg.get("beltway").__name__ == "corridor.traffic.networks.beltway"
    with pytest.raises(UnknownName, match=r"^unknown network kind 'nope'; known: beltway, flow_merge, highway_onramp"):
        reg.get("nope")
