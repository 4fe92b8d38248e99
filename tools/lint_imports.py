"""Run import-linter (``lint-imports``) on corridor's import contracts (``[tool.importlinter]`` in
pyproject.toml).

The top-level folders map into one namespace through setuptools ``package-dir`` (``traffic/`` is
``corridor.traffic``), but import-linter builds its graph by walking the root package's folder, so it
would not see the domain packages.  This mirrors the packages into one temporary ``corridor/`` tree
(copies of the ``.py`` files, no data) and runs ``lint-imports`` on it; the import graph is the
installed package's.  Extra arguments go to ``lint-imports`` (e.g. ``--verbose``).

    python tools/lint_imports.py             # exit 0: every contract kept
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def mirror(dest: Path, root: Path = ROOT) -> Path:
    """Copy every package of ``package-dir`` into ``dest`` as one tree; returns ``dest``."""
    cfg = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    for package, folder in sorted(cfg["package-dir"].items()):
        target = dest.joinpath(*package.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for src in (root / folder).rglob("*.py"):
            rel = src.relative_to(root / folder)
            if "__pycache__" in rel.parts:
                continue
            (target / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, target / rel)
    return dest


def lint(tree: Path, argv: list[str]) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on a mirrored tree (``tree/corridor``); output captured."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    if exe is None:
        raise FileNotFoundError("lint-imports not found: pip install -e '.[dev]'")
    # the mirror, and tools/ for corridor's own contract type (import_rules.py)
    path = [str(tree), str(ROOT / "tools"), os.environ.get("PYTHONPATH")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, path))}
    # cwd = the mirror: lint-imports puts the working directory first on sys.path
    return subprocess.run([exe, "--no-cache", *argv], env=env, cwd=tree, capture_output=True, text=True)


def main(argv: list[str]) -> int:
    argv = list(argv)
    for i, a in enumerate(argv[:-1]):
        if a == "--config":
            argv[i + 1] = str(Path(argv[i + 1]).resolve())
    if "--config" not in argv:
        argv = ["--config", str(ROOT / "pyproject.toml"), *argv]
    with tempfile.TemporaryDirectory(prefix="corridor-imports-") as tmp:
        try:
            proc = lint(mirror(Path(tmp)), argv)
        except FileNotFoundError as exc:
            print(f"lint_imports: {exc}", file=sys.stderr)
            return 2
        sys.stdout.write(proc.stdout)
        sys.stderr.write(proc.stderr)
        return proc.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
