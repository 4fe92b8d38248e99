"""Reading scenario files: a safe YAML loader with limits, and the ``extends:`` chain.

``read_yaml`` reads one file (a regular UTF-8 file of at most ``MAX_FILE_BYTES``, no duplicate keys,
bounded nesting and alias expansion) and refuses a file that is not a scenario without echoing it;
``resolve_extends`` merges the chain of files a scenario extends.
"""

from __future__ import annotations

import copy
import difflib
import re
import stat
from pathlib import Path
from typing import Any

import yaml

from corridor.errors import ScenarioError, clip
from corridor.scenario.messages import show_path
from corridor.scenario.schema import MAX_FILE_BYTES, MAX_YAML_DEPTH, MAX_YAML_NODES, SHORTHANDS, Scenario


class _LimitError(yaml.MarkedYAMLError):
    """A loader limit or a duplicate key; its ``problem`` holds no file content beyond what it names."""


class _Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with limits.

    A nesting limit, an alias-expansion limit (nodes counted as if every alias were a copy), no
    recursive aliases and no duplicate keys.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0
        self._sizes: dict[int, int] = {}  # id(node) -> its size once expanded (set when composed)
        self.root_key_lines: dict[Any, int] | None = None  # the document's top-level keys -> line (0-based)

    def _count(self, n: int, mark: Any) -> None:
        self._nodes += n
        if self._nodes > MAX_YAML_NODES:
            raise _LimitError(problem=f"more than {MAX_YAML_NODES} values once aliases are expanded", problem_mark=mark)

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()  # type: ignore[no-untyped-call]
            node = self.anchors.get(event.anchor)
            if node is not None:
                if id(node) not in self._sizes:
                    raise _LimitError(problem="an alias inside its own anchor (recursive data)",
                                      problem_mark=event.start_mark)
                self._count(self._sizes[id(node)], event.start_mark)
            return super().compose_node(parent, index)
        mark = self.peek_event().start_mark  # type: ignore[no-untyped-call]
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise _LimitError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels", problem_mark=mark)
        start = self._nodes
        self._count(1, mark)
        node = super().compose_node(parent, index)
        self._depth -= 1
        self._sizes[id(node)] = self._nodes - start
        return node

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    line = first.get(key)
                except TypeError:  # unhashable: the base class says so
                    continue
                if line is not None:
                    raise _LimitError(problem=f"duplicate key {clip(key, 40)} (lines {line + 1} and "
                                              f"{key_node.start_mark.line + 1})", problem_mark=key_node.start_mark)
                first[key] = key_node.start_mark.line
            if self.root_key_lines is None:  # the root mapping is constructed first
                self.root_key_lines = first
        return super().construct_mapping(node, deep=deep)


def load_yaml_text(text: str) -> Any:
    """The document of a YAML text, read with the safe loader's limits (``yaml.YAMLError`` if not)."""
    return _yaml_load_lines(text)[0]


def _yaml_load_lines(text: str) -> tuple[Any, dict[Any, int]]:
    """The document and the lines of its top-level keys."""
    loader = _Loader(text)
    try:
        return loader.get_single_data(), loader.root_key_lines or {}
    finally:
        loader.dispose()


_QUOTED = re.compile(r"'[^']*'|\"[^\"]*\"")  # what PyYAML quotes in a problem: a token name or the file's text
_HARMLESS = re.compile(r"[^A-Za-z0-9\s]{1,3}|<[a-z ]+>")  # ':' or '<block end>' say no more than the syntax


def _yaml_problem(exc: Exception) -> str:
    """Where and what of a YAML error, without the file's text.

    PyYAML quotes the offending characters (and ``str(exc)`` the offending line), which for a file
    that is not a scenario (``extends: /etc/shadow``) is its content.  Keeps the line/column and the
    generic part of the reason.
    """
    if isinstance(exc, yaml.reader.ReaderError):
        return f"position {exc.position}: {exc.reason}"
    if not isinstance(exc, yaml.MarkedYAMLError):
        return "a value cannot be read (e.g. an invalid date or a too long number)"
    mark = exc.problem_mark
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
    problem = exc.problem or "syntax error"
    if not isinstance(exc, _LimitError):
        problem = _QUOTED.sub(lambda m: m[0] if _HARMLESS.fullmatch(m[0][1:-1]) else "…", problem)
    return f"{where}{clip(problem, 120)[1:-1]}"


def read_text(path: Path) -> str:
    """A scenario file's text: a regular UTF-8 file of at most ``MAX_FILE_BYTES``."""
    try:
        st = path.stat()
    except ValueError:
        raise ScenarioError(f"{show_path(path)}: a path cannot contain a NUL byte") from None
    except FileNotFoundError:
        raise ScenarioError(f"{show_path(path)}: no such file") from None
    except (OSError, RuntimeError) as exc:  # symlink loop, name too long, permission denied, ...
        raise ScenarioError(f"{show_path(path)}: cannot read ({getattr(exc, 'strerror', None) or 'symlink loop'})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"{show_path(path)}: is a directory, not a scenario file")
    if not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{show_path(path)}: not a regular file")
    if st.st_size > MAX_FILE_BYTES:
        raise ScenarioError(f"{show_path(path)}: larger than {MAX_FILE_BYTES // 1000} kB, not a scenario file")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"{show_path(path)}: cannot read ({exc.strerror or 'I/O error'})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ScenarioError(f"{show_path(path)}: larger than {MAX_FILE_BYTES // 1000} kB, not a scenario file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{show_path(path)}: not a UTF-8 text file (byte {exc.start})") from None


def read_yaml(path: Path) -> dict[str, Any]:
    """The raw mapping of a scenario file, read with the safe loader's limits.

    Raises:
        ScenarioError: one line: invalid YAML, not a mapping, or not a scenario file (its keys are
            not echoed).
    """
    text = read_text(path)
    try:
        data, lines = _yaml_load_lines(text)
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError) as exc:
        raise ScenarioError(f"{show_path(path)}: invalid YAML: {_yaml_problem(exc)}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{show_path(path)}: a scenario must be a YAML mapping, got {type(data).__name__}")
    fields = [*Scenario.model_fields, *SHORTHANDS, "extends"]
    for key in data:  # a mapping of other keys is some other file (/etc/shadow is one): do not echo it
        if key in fields or isinstance(key, str) and difflib.get_close_matches(key[:80], fields, n=1, cutoff=0.75):
            continue  # a field, or a typo of one that validation names with a hint
        raise ScenarioError(f"{show_path(path)}: not a scenario file: the top-level key at line "
                            f"{lines.get(key, -1) + 1} is not a scenario field")
    return data


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``base`` with ``over`` merged in, mapping by mapping (``over`` wins)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


MAX_EXTENDS = 16  # files in one extends chain


def resolve_extends(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The raw data of a scenario file with its ``extends:`` chain merged (a cycle is an error)."""
    try:
        real = path.resolve()
    except (OSError, RuntimeError, ValueError):  # NUL byte, symlink loop (3.11 raises RuntimeError)
        read_text(path)  # raises the one-line reason
        raise ScenarioError(f"{show_path(path)}: cannot resolve this path") from None
    if real in seen:
        raise ScenarioError(f"{show_path(real)}: extends: cycle through {' -> '.join(show_path(p.name) for p in seen)}")
    if len(seen) >= MAX_EXTENDS:
        raise ScenarioError(f"{show_path(real)}: extends: more than {MAX_EXTENDS} files in the chain")
    data = read_yaml(real)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str) or not parent:
        raise ScenarioError(f"{show_path(real)}: extends: must be a file path, got {type(parent).__name__}")
    return deep_merge(resolve_extends(real.parent / parent, (*seen, real)), data)
