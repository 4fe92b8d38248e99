#!/usr/bin/env python3
"""Rewrite every old dotted path of corridor to its new one, as listed in ``moved_modules.tsv`` (issue 29).

    python rewrite_imports.py TREE [--moves tools/moved_modules.tsv] [--exclude README.md ...] [--dry-run]

``moved_modules.tsv`` holds one move a line: ``old.dotted.path<TAB>new.dotted.path`` (a module, a package
or a moved symbol such as ``corridor.controllers.uav.models.TrackedAgent``).  In every text file of
TREE (Python, TOML, Markdown, YAML, Makefile, ...) it rewrites

- ``from OLD import a, b`` (also parenthesised, multi-line): the module path, and names that moved
  on their own (a moved symbol, or a moved submodule imported as ``from corridor.traffic import
  monitors``) are split into their own ``from NEW_PARENT import name [as old_name]`` line;
- relative imports (``from .air_backend import air_rows``) of a module that moved, or inside a
  module that moved, into absolute ones (resolved against the module's OLD package);
- every other occurrence of an old dotted path: ``import OLD``, ``OLD:Class`` entry points,
  ``"OLD.attr"`` mock/monkeypatch targets, docstrings, docs;
- file paths of moved modules (``traffic/monitors.py`` -> ``analysis/monitoring/road.py``), from the
  ``package-dir`` table of TREE/pyproject.toml.

Run it on the MERGED tree (the moved files at their new places: relative imports are resolved from
where a file now is back to its old package), then ``ruff check --fix --select I .`` to re-sort the
import blocks it split.  It skips .git, .venv, build, results and site; pass ``--exclude README.md``
to leave a file alone.  Not covered: ``python -m corridor.traffic.calibrate`` (the command moved to
``corridor.analysis.calibration``, see moved_modules.tsv), and the removed ``MavlinkLink.receive_latest`` /
``ReceivedReport`` (use ``receive`` or ``receive_latest_table``).

Longest match first, whole dotted names only (``corridor.vehicles.camera`` never touches
``corridor.vehicles.camera_sensor``), one pass per file, and idempotent: a new path that extends an
old one (``corridor.analysis.monitors`` -> ``corridor.analysis.monitoring.collisions``) is never
rewritten again, so the script can run on a tree where old and new references are mixed (a merge).
Prints the files it changed; exit 0.
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent
SUFFIXES = {".py", ".toml", ".md", ".yaml", ".yml", ".txt", ".cfg", ".ini", ".rst", ".pyi"}
NAMES = {"Makefile"}
SKIP_DIRS = {".git", ".venv", "build", "dist", "results", "site", "__pycache__", "node_modules", ".cache"}


def read_moves(path: Path) -> dict[str, str]:
    """old -> new from a TSV file (comments and blank lines skipped)."""
    moves: dict[str, str] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split("\t")
        if len(parts) != 2 or not all(parts):
            raise SystemExit(f"{path}:{n}: expected 'old<TAB>new', got {line!r}")
        moves[parts[0].strip()] = parts[1].strip()
    return moves


class Mapper:
    """Maps dotted paths (and file paths) through the moves, longest old prefix first."""

    def __init__(self, moves: dict[str, str], package_dirs: dict[str, str]) -> None:
        self.moves = moves
        olds = sorted(moves, key=len, reverse=True)
        news = set(moves.values())
        alts = []
        for old in olds:
            # idempotency: a new path that starts with this old one (old module -> package of that
            # name) is already rewritten; do not extend it again
            tails = sorted({n[len(old) + 1:].split(".")[0] for n in news if n.startswith(old + ".")})
            guard = "".join(rf"(?!\.{re.escape(t)}\b)" for t in tails)
            alts.append(re.escape(old) + guard)
        self.dotted = re.compile(r"(?<![\w.])(?:" + "|".join(alts) + r")(?![\w])") if alts else None
        self.file_moves = self._file_moves(package_dirs)
        falts = [re.escape(old) for old in sorted(self.file_moves, key=len, reverse=True)]
        self.files = re.compile(r"(?<![\w./-])(?:" + "|".join(falts) + r")(?![\w])") if falts else None

    def map(self, path: str) -> str:
        """The new dotted path of ``path`` (itself when nothing moved)."""
        for old in sorted(self.moves, key=len, reverse=True):
            if path == old or path.startswith(old + "."):
                new = self.moves[old]
                # idempotent: a path already in the new form is left alone
                rest = path[len(old):]
                if any(n.startswith(old + ".") and (path == n or path.startswith(n + "."))
                       for n in self.moves.values()):
                    return path
                return new + rest
        return path

    def _file_moves(self, package_dirs: dict[str, str]) -> dict[str, str]:
        """``traffic/monitors.py`` -> ``analysis/monitors/road.py`` for every module move."""

        def to_file(dotted: str, package: bool) -> str | None:
            for pkg in sorted(package_dirs, key=len, reverse=True):
                if dotted == pkg or dotted.startswith(pkg + "."):
                    rel = dotted[len(pkg) + 1:].replace(".", "/") if dotted != pkg else ""
                    base = package_dirs[pkg].rstrip("/")
                    stem = f"{base}/{rel}" if rel else base
                    return stem if package else stem + ".py"
            return None

        out: dict[str, str] = {}
        for old, new in self.moves.items():
            leaf = old.rsplit(".", 1)[-1]
            if leaf[:1].isupper():
                continue  # a class or constant, not a file
            is_package = any(k.startswith(old + ".") and "." not in k[len(old) + 1:] and
                             not k[len(old) + 1:][:1].isupper() for k in self.moves)
            a, b = to_file(old, is_package), to_file(new, is_package)
            if a and b and a != b:
                out[a] = b
        return out

    def sub_dotted(self, text: str) -> str:
        if self.dotted is None:
            return text
        return self.dotted.sub(lambda m: self.map(m.group(0)), text)

    def sub_files(self, text: str) -> str:
        if self.files is None:
            return text
        return self.files.sub(lambda m: self.file_moves[m.group(0)], text)


FROM_IMPORT = re.compile(
    r"(?:^|(?<=\\n)|(?<=[\"']))(?P<indent>[ \t]*)from[ \t]+(?P<mod>\.*[\w.]*)[ \t]+import[ \t]+"
    r"(?P<names>\((?:[^)#]|#[^\n]*)*\)|[^\n(]*?(?:\\\n[^\n]*?)*)(?P<tail>[ \t]*(?:#[^\n]*)?)$",
    re.MULTILINE,
)


def _parse_names(blob: str) -> list[tuple[str, str | None]] | None:
    """``a, b as c`` -> [(a, None), (b, c)]; None when the list holds comments (left alone)."""
    body = blob.strip()
    if body.startswith("("):
        body = body[1:-1]
    if "#" in body:
        return None
    body = body.replace("\\\n", " ")
    out: list[tuple[str, str | None]] = []
    for part in body.split(","):
        part = part.strip()
        if not part:
            continue
        bits = part.split()
        if len(bits) == 1:
            out.append((bits[0], None))
        elif len(bits) == 3 and bits[1] == "as":
            out.append((bits[0], bits[2]))
        else:
            return None
    return out


def _format(indent: str, module: str, names: list[tuple[str, str | None]], multiline: bool, tail: str) -> str:
    items = [n if a is None else f"{n} as {a}" for n, a in names]
    one = f"{indent}from {module} import {', '.join(items)}"
    if not multiline or len(items) == 1:
        return one + tail
    inner = "".join(f"{indent}    {i},\n" for i in items)
    return f"{indent}from {module} import (\n{inner}{indent})" + tail


def resolve_relative(mod: str, package: str) -> str:
    """``..x`` inside ``package`` -> absolute dotted path."""
    level = len(mod) - len(mod.lstrip("."))
    parts = package.split(".")
    base = parts[: len(parts) - (level - 1)] if level > 1 else parts
    rest = mod[level:]
    return ".".join(base + ([rest] if rest else []))


def rewrite_from(m: re.Match[str], mapper: Mapper, old_package: str | None, moved_file: bool) -> str:
    indent, mod, blob, tail = m.group("indent"), m.group("mod"), m.group("names"), m.group("tail")
    whole = m.group(0)
    if mod.startswith("."):
        if old_package is None:
            return whole
        absolute = resolve_relative(mod, old_package)
        names = _parse_names(blob)
        touched = moved_file or mapper.map(absolute) != absolute or any(
            mapper.map(f"{absolute}.{n}") != f"{absolute}.{n}" for n, _ in (names or []))
        if not touched:
            return whole
        mod = absolute
    names = _parse_names(blob)
    if names is None:  # comments inside the list: only the module path
        return f"{indent}from {mapper.map(mod)} import {blob}{tail}"
    new_mod = mapper.map(mod)
    groups: dict[str, list[tuple[str, str | None]]] = {}
    for name, alias in names:
        full = f"{mod}.{name}"
        target = mapper.map(full) if full in mapper.moves or _exact_prefix(mapper, full) else None
        if target is None or target == f"{new_mod}.{name}":
            groups.setdefault(new_mod, []).append((name, alias))
            continue
        parent, leaf = target.rsplit(".", 1)
        groups.setdefault(parent, []).append((leaf, alias if alias else (name if leaf != name else None)))
    if list(groups) == [new_mod]:  # no name moved on its own: only the module path changes
        if new_mod == mod and not m.group("mod").startswith("."):
            return whole
        start = m.start("mod") - m.start()
        return whole[:start] + new_mod + whole[start + len(m.group("mod")):]
    multiline = blob.strip().startswith("(")
    lines = [_format(indent, k, v, multiline, "") for k, v in groups.items()]
    lines[-1] += tail
    return "\n".join(lines)


def _exact_prefix(mapper: Mapper, full: str) -> bool:
    """True when ``full`` (module.name) is itself a moved entry or lies under one that is not the
    module's own entry (a moved symbol/submodule)."""
    return full in mapper.moves


def module_of(path: Path, root: Path, package_dirs: dict[str, str]) -> str | None:
    """Dotted module of a .py file of the tree (through package-dir), None outside the packages."""
    rel = path.relative_to(root).as_posix()
    for pkg, folder in sorted(package_dirs.items(), key=lambda kv: len(kv[1]), reverse=True):
        folder = folder.rstrip("/")
        if rel.startswith(folder + "/"):
            sub = rel[len(folder) + 1:-3].replace("/", ".")
            if sub.endswith("__init__"):
                sub = sub[: -len("__init__")].rstrip(".")
            return f"{pkg}.{sub}" if sub else pkg
    return None


def rewrite_text(text: str, mapper: Mapper, old_package: str | None, moved_file: bool, python: bool) -> str:
    """One pass: from-imports (Python only) by their own rule, everything else by the dotted map."""
    out, pos = [], 0
    if python:
        for m in FROM_IMPORT.finditer(text):
            out.append(mapper.sub_files(mapper.sub_dotted(text[pos:m.start()])))
            out.append(rewrite_from(m, mapper, old_package, moved_file))
            pos = m.end()
    out.append(mapper.sub_files(mapper.sub_dotted(text[pos:])))
    return "".join(out)


def files_of(root: Path, exclude: set[str]) -> list[Path]:
    out = []
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if any(part in SKIP_DIRS or part.endswith(".egg-info") for part in rel.parts):
            continue
        if rel.as_posix() in exclude or not p.is_file():
            continue
        if p.suffix in SUFFIXES or p.name in NAMES:
            out.append(p)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tree", type=Path)
    ap.add_argument("--moves", type=Path, default=HERE / "moved_modules.tsv")
    ap.add_argument("--exclude", action="append", default=[], help="path relative to TREE (repeatable)")
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args(argv)
    root = a.tree.resolve()
    moves = read_moves(a.moves)
    pyproject = root / "pyproject.toml"
    package_dirs = {}
    if pyproject.is_file():
        package_dirs = tomllib.loads(pyproject.read_text()).get("tool", {}).get("setuptools", {}).get("package-dir", {})
    mapper = Mapper(moves, package_dirs)
    inverse = {new: old for old, new in moves.items()}
    changed = 0
    for path in files_of(root, set(a.exclude)):
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        python = path.suffix in {".py", ".pyi"}
        old_package, moved_file = None, False
        if python:
            module = module_of(path, root, package_dirs)
            if module is not None:
                old_module = inverse.get(module, module)
                moved_file = old_module != module
                is_pkg = path.name == "__init__.py"
                old_package = old_module if is_pkg else old_module.rsplit(".", 1)[0]
        new = rewrite_text(text, mapper, old_package, moved_file, python)
        if new != text:
            changed += 1
            print(path.relative_to(root))
            if not a.dry_run:
                path.write_text(new)
    print(f"rewrite_imports: {changed} file(s) {'would change' if a.dry_run else 'changed'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
