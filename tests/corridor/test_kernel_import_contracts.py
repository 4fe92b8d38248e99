"""The import-linter contracts of pyproject.toml hold, and a deliberate violation breaks them."""

from __future__ import annotations

import importlib.util
import sys
import tempfile
from pathlib import Path

from tests.conftest import REPO

spec = importlib.util.spec_from_file_location("lint_imports", REPO / "tools" / "lint_imports.py")
lint_imports = importlib.util.module_from_spec(spec)
sys.modules["lint_imports"] = lint_imports
spec.loader.exec_module(lint_imports)

CONFIG = ["--config", str(REPO / "pyproject.toml")]


def test_the_contracts_hold():
    with tempfile.TemporaryDirectory() as tmp:
        proc = lint_imports.lint(lint_imports.mirror(Path(tmp)), CONFIG)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "4 kept, 0 broken" in proc.stdout


def test_a_kernel_module_importing_a_domain_package_breaks_the_contracts():
    with tempfile.TemporaryDirectory() as tmp:
        tree = lint_imports.mirror(Path(tmp))
        with open(tree / "corridor" / "events.py", "a") as f:  # the kernel reaching into traffic
            f.write("\nfrom corridor.traffic.sumo import commands  # noqa: E402,F401\n")
        with open(tree / "corridor" / "controllers" / "ramp_metering" / "alinea.py", "a") as f:  # an algorithm using SUMO
            f.write("\nimport libsumo  # noqa: E402,F401\n")
        proc = lint_imports.lint(tree, CONFIG)
    assert proc.returncode != 0
    out = proc.stdout
    assert "Domains along the tick" in out and "BROKEN" in out
    assert "corridor.events -> corridor.traffic.sumo.commands" in out
    assert "corridor.controllers.ramp_metering.alinea -> libsumo" in out
    assert "1 kept, 3 broken" in out, out[-3000:]  # kernel layers, algorithms, libsumo; jsbsim kept


def _broken(edits: dict[str, str]) -> str:
    """lint-imports output on a mirror of the tree with ``edits`` (path in the mirror -> appended
    source); asserts that the contracts fail."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = lint_imports.mirror(Path(tmp))
        for rel, code in edits.items():
            with open(tree / rel, "a") as f:
                f.write(code)
        proc = lint_imports.lint(tree, CONFIG)
    assert proc.returncode != 0, proc.stdout[-3000:]
    return proc.stdout


def test_an_import_against_the_tick_breaks_the_layers() -> None:
    """The domains are ordered, not siblings: the road (traffic) importing a controller, or a vehicle
    importing the analysis, is a broken layer contract; the reverse directions are allowed."""
    out = _broken({
        "corridor/traffic/v2x.py": "\nfrom corridor.controllers.merging import coordinator  # noqa: E402,F401\n",
        "corridor/vehicles/geodesy.py": "\nfrom corridor.analysis import safety  # noqa: E402,F401\n",
    })
    assert "Domains along the tick" in out and "BROKEN" in out
    assert "corridor.traffic.v2x -> corridor.controllers.merging.coordinator" in out
    assert "corridor.vehicles.geodesy -> corridor.analysis.safety" in out
    assert "Contracts: 3 kept, 1 broken" in out, out[-2000:]


def test_a_new_algorithm_module_is_checked_without_being_listed() -> None:
    """The algorithms contract is a rule per package: a module nobody named (a new file under
    controllers/) that imports the engine breaks it; the same import in a components module does not."""
    new = "corridor/controllers/merging/new_policy.py"
    with tempfile.TemporaryDirectory() as tmp:
        tree = lint_imports.mirror(Path(tmp))
        (tree / new).write_text("from corridor.engine import Controller  # noqa: F401\n")
        with open(tree / "corridor/controllers/uav/components.py", "a") as f:  # an adapter: allowed
            f.write("\nfrom corridor import run  # noqa: E402,F401\n")
        proc = lint_imports.lint(tree, CONFIG)
    out = proc.stdout
    assert proc.returncode != 0
    assert "corridor.controllers.merging.new_policy -> corridor.engine" in out
    assert "corridor.controllers.uav.components -> corridor.run" not in out
    assert "Contracts: 3 kept, 1 broken" in out, out[-2000:]


def test_except_patterns_match_whole_segments() -> None:
    rules = _import_rules()
    assert rules.matches("corridor.controllers.ramp_metering.metanet_components", "corridor.controllers.*.*components")
    assert rules.matches("corridor.controllers.uav.components", "corridor.controllers.*.*components")
    assert not rules.matches("corridor.controllers.uav.components_x", "corridor.controllers.*.*components")
    assert not rules.matches("corridor.controllers.uav.sub.components", "corridor.controllers.*.*components")


def _import_rules():
    spec = importlib.util.spec_from_file_location("import_rules", REPO / "tools" / "import_rules.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_kernel_has_no_import_cycle() -> None:
    """No two kernel modules import each other, not even lazily inside a function (api, cli and
    rare_api did through ``resolve_scenario``; scenario and distributions through ``Distribution``)."""
    with tempfile.TemporaryDirectory() as tmp:
        cycles = lint_imports.kernel_cycles(lint_imports.mirror(Path(tmp)))
    assert cycles == []


def test_a_lazy_import_back_is_a_kernel_cycle() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tree = lint_imports.mirror(Path(tmp))
        with open(tree / "corridor" / "errors.py", "a") as f:  # errors <- api, and now errors -> api
            f.write("\n\ndef _late():\n    from corridor import api  # noqa: F401\n")
        cycles = lint_imports.kernel_cycles(tree)
    assert len(cycles) == 1 and "corridor.api" in cycles[0] and "corridor.errors" in cycles[0], cycles
