"""Run import-linter (``lint-imports``) on corridor's import contracts (``[tool.importlinter]`` in
pyproject.toml).

The top-level folders map into one namespace through setuptools ``package-dir`` (``traffic/`` is
``corridor.traffic``), but import-linter builds its graph by walking the root package's folder, so it
would not see the domain packages.  This mirrors the packages into one temporary ``corridor/`` tree
(copies of the ``.py`` files, no data) and runs ``lint-imports`` on it; the import graph is the
installed package's.  Extra arguments go to ``lint-imports`` (e.g. ``--verbose``).

It then checks that the kernel (``corridor/`` without the domain packages) has no import cycle: no
two kernel modules import each other, directly or through others, counting every import statement
(inside functions and ``TYPE_CHECKING`` blocks too), with grimp, the graph library of import-linter.

    python tools/lint_imports.py             # exit 0: every contract kept, no kernel import cycle
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
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


# Run in a child process on the mirror (the installed corridor is not the mirrored tree): prints one
# cycle a line, modules joined by " -> ".  Strongly connected components of the kernel's import graph
# (Tarjan), each shown as one cycle through all of its modules' shortest chains.
_CYCLES = textwrap.dedent("""
    import sys, grimp
    domains = set(sys.argv[1].split(","))
    graph = grimp.build_graph("corridor", cache_dir=None)
    kernel = sorted(m for m in graph.modules if m.startswith("corridor")
                    and not (m.split(".") + [""])[1] in domains)
    edges = {m: sorted(n for n in graph.find_modules_directly_imported_by(m) if n in kernel and n != m)
             for m in kernel}
    index, low, stack, on, sccs = {}, {}, [], set(), []
    def visit(v):
        index[v] = low[v] = len(index); stack.append(v); on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w); low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop(); on.discard(w); scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                sccs.append(sorted(scc))
    sys.setrecursionlimit(10000)
    for v in kernel:
        if v not in index:
            visit(v)
    for scc in sccs:
        print(" <-> ".join(scc))
""")


def domains(root: Path = ROOT) -> list[str]:
    """The domain packages (``traffic``, ``vehicles``, ...): every ``package-dir`` entry but the kernel."""
    cfg = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    return sorted(p.split(".")[1] for p in cfg["package-dir"] if p.count(".") == 1)


def kernel_cycles(tree: Path) -> list[str]:
    """The import cycles among the kernel's modules of a mirrored tree, one line each (empty: none).

    Each line lists the modules of one strongly connected component (``a <-> b <-> c``): every one of
    them reaches every other through imports.
    """
    env = {**os.environ, "PYTHONPATH": str(tree)}
    proc = subprocess.run([sys.executable, "-c", _CYCLES, ",".join(domains())], env=env, cwd=tree,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"grimp failed: {proc.stderr.strip().splitlines()[-1:]}")
    return proc.stdout.splitlines()


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
        cycles = kernel_cycles(Path(tmp))
    for line in cycles:
        print(f"kernel import cycle: {line}")
    print(f"kernel import cycles: {len(cycles)}")
    return proc.returncode or (1 if cycles else 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
