"""The import-linter contracts of pyproject.toml hold, and a deliberate violation breaks them."""

from __future__ import annotations

import importlib.util
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("lint_imports", ROOT / "tools" / "lint_imports.py")
lint_imports = importlib.util.module_from_spec(spec)
sys.modules["lint_imports"] = lint_imports
spec.loader.exec_module(lint_imports)

CONFIG = ["--config", str(ROOT / "pyproject.toml")]


def test_the_contracts_hold():
    with tempfile.TemporaryDirectory() as tmp:
        proc = lint_imports.lint(lint_imports.mirror(Path(tmp)), CONFIG)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "4 kept, 0 broken" in proc.stdout


def test_a_kernel_module_importing_a_domain_package_breaks_the_contracts():
    with tempfile.TemporaryDirectory() as tmp:
        tree = lint_imports.mirror(Path(tmp))
        with open(tree / "corridor" / "events.py", "a") as f:  # the kernel reaching into traffic
            f.write("\nfrom corridor.traffic import commands  # noqa: E402,F401\n")
        with open(tree / "corridor" / "controllers" / "ramp_metering" / "alinea.py", "a") as f:  # an algorithm using SUMO
            f.write("\nimport libsumo  # noqa: E402,F401\n")
        proc = lint_imports.lint(tree, CONFIG)
    assert proc.returncode != 0
    out = proc.stdout
    assert "Domains along the tick" in out and "BROKEN" in out
    assert "corridor.events -> corridor.traffic.sumo.commands" in out
    assert "corridor.controllers.ramp_metering.alinea -> libsumo" in out
    assert "1 kept, 3 broken" in out, out[-3000:]  # kernel layers, algorithms, libsumo; jsbsim kept
