"""A user's package adds a controller through the ``corridor.components`` entry-point group, without
editing corridor: tests/plugins/corridor_example_plugin is installed into a temporary folder (its
package plus a ``.dist-info`` with the entry points of its pyproject.toml, which is what an install
writes) and a scenario that uses its controller runs in a subprocess with that folder on PYTHONPATH."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

from tests.conftest import REPO

PLUGIN = REPO / "tests" / "plugins" / "corridor_example_plugin"


def install(target: Path) -> None:
    """What ``pip install --target`` leaves behind, without a build: the package and its metadata."""
    meta = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    shutil.copytree(PLUGIN / "corridor_example_plugin", target / "corridor_example_plugin")
    info = target / f"{meta['name'].replace('-', '_')}-{meta['version']}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {meta['version']}\n")
    lines = []
    for group, entries in meta["entry-points"].items():
        lines += [f"[{group}]", *(f"{name} = {value}" for name, value in entries.items()), ""]
    (info / "entry_points.txt").write_text("\n".join(lines))


RUN = """
import json, sys
from corridor.api import run
res = run(sys.argv[1], variants=["none", "open"], out=sys.argv[2], report=False)
print(json.dumps(res.rows[["variant", "status", "error", "tts_vh", "example_meter.rate",
                           "example_meter.commands"]].to_dict("records")))
"""


def test_a_plugin_controller_runs_in_a_scenario(tmp_path):
    install(tmp_path / "site")
    scenario = tmp_path / "plugin.yaml"
    scenario.write_text(f"extends: {REPO / 'scenarios' / 'hegyi_benchmark.yaml'}\n"
                        "name: plugin\nduration: 3600\n"
                        "controllers: {meter: {type: example_fixed_meter, params: {rate: 0.2}}}\n"
                        "sweep: {open: {controllers.meter: {type: none}}}\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path / "site"),
                                                                     os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-c", RUN, str(scenario), str(tmp_path / "out")], env=env,
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = {r["variant"]: r for r in json.loads(proc.stdout.strip().splitlines()[-1])}
    plugin, open_ = rows["none"], rows["open"]
    assert plugin["status"] == "ok" and open_["status"] == "ok", (plugin["error"], open_["error"])
    assert plugin["example_meter.rate"] == 0.2 and plugin["example_meter.commands"] == 3600 / 60
    assert plugin["tts_vh"] != open_["tts_vh"]  # the meter held at 20 % changes the traffic


def test_without_the_plugin_its_type_is_one_clear_line(tmp_path):
    scenario = tmp_path / "plugin.yaml"
    scenario.write_text(f"extends: {REPO / 'scenarios' / 'hegyi_benchmark.yaml'}\n"
                        "controllers: {meter: {type: example_fixed_meter}}\n")
    proc = subprocess.run([sys.executable, "-m", "corridor.cli", str(scenario), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"run_scenario: {scenario}: controllers.meter.type: unknown controller 'example_fixed_meter' "
        "(did you mean 'ramp_fixed'?)"]


RING = """
import json, sys
from corridor.api import run
res = run(sys.argv[1], out=sys.argv[2], report=False)
print(json.dumps(res.rows[["status", "error", "vehicles_departed", "vehicles_arrived"]].to_dict("records")))
"""


def test_a_plugin_network_builder_runs_in_a_scenario(tmp_path):
    """A plug-in adds a road network by the ``corridor.networks`` entry point (no edit of corridor)."""
    install(tmp_path / "site")
    scenario = tmp_path / "ring.yaml"
    scenario.write_text("name: ring\nduration: 120\nroad:\n  network: {type: example_ring, params: {edges: 5}}\n"
                        "  demand: {flows: {f: {route: loop, flow_vph: 600, arrivals: uniform}}}\n"
                        "controllers:\n  merge: {type: v2x_merging}\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path / "site"),
                                                                     os.environ.get("PYTHONPATH")])),
           "CORRIDOR_CACHE": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-m", "corridor.cli", str(scenario), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env)
    assert proc.returncode == 2  # its landmarks are known at load: no merge on a ring
    assert "V2X merging needs the landmarks of a highway_onramp network" in proc.stderr
    assert "'example_ring' has none" in proc.stderr
    scenario.write_text(scenario.read_text().split("controllers:")[0])
    proc = subprocess.run([sys.executable, "-c", RING, str(scenario), str(tmp_path / "out")], env=env,
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (row,) = json.loads(proc.stdout.strip().splitlines()[-1])
    assert row["status"] == "ok", row["error"]
    assert row["vehicles_departed"] == 20 and row["vehicles_arrived"] > 10  # 600 veh/h for 120 s, uniform
