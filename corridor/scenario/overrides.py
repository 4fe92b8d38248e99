"""Overrides of a scenario's raw data: ``--set a.b=c``, sweep variants and randomized draws.

All three are ``dotted.path: value`` maps applied to the raw data before validation; ``road:`` and
the other shorthands are reached by either spelling (``road.x`` is ``backends.road.params.x``).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from corridor.errors import ScenarioError, clip
from corridor.scenario.schema import MAX_YAML_DEPTH, SHORTHANDS
from corridor.scenario.yaml_load import load_yaml_text, resolve_extends


def parse_value(text: str) -> Any:
    """``--set`` values are YAML scalars/flows: ``3``, ``0.5``, ``true``, ``[1, 2]``, ``{a: 1}``."""
    try:
        return load_yaml_text(text)
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError):
        return text


def _keyed_by_paths(prefix: list[str]) -> bool:
    """``randomize`` and each ``sweep`` variant are maps keyed by whole dotted paths."""
    return prefix == ["randomize"] or (len(prefix) == 2 and prefix[0] == "sweep")


def set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``a.b.0.c`` in nested dicts/lists, creating dicts on the way (validation catches typos).

    Below ``randomize`` and ``sweep.<variant>`` the keys are dotted paths themselves: the rest of the
    path is matched against them (``sweep.v2x_cps.controllers.merge.params.policy`` sets ``policy`` in
    the variant's ``controllers.merge`` entry) or becomes a new key (``sweep.v2x_cps.duration``).
    """
    keys = respell(data, dotted.split("."))
    if len(keys) > MAX_YAML_DEPTH:
        raise ScenarioError(f"{clip(dotted)}: more than {MAX_YAML_DEPTH} levels")
    node: Any = data
    i = 0
    while i < len(keys):
        key = keys[i]
        last = i == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise ScenarioError(f"{clip('.'.join(keys[:i + 1]))}: no list item {clip(key, 20)}")
            if last:
                node[int(key)] = value
            else:
                node = node[int(key)]
            i += 1
            continue
        if not isinstance(node, dict):
            raise ScenarioError(f"{clip('.'.join(keys[:i]))}: is a value, cannot set {clip(dotted)} below it")
        if _keyed_by_paths(keys[:i]):
            rest = keys[i:]
            match = max((k for k in node if isinstance(k, str) and k.split(".") == rest[:k.count(".") + 1]),
                        key=len, default=None)
            if match is None or match.count(".") + 1 == len(rest):
                node[match or ".".join(rest)] = value
                return
            node = node[match]
            i += match.count(".") + 1
            continue
        if last:
            node[key] = value
        else:
            if not isinstance(node.get(key), dict | list):
                node[key] = {}
            node = node[key]
        i += 1


def respell(data: Any, keys: list[str]) -> list[str]:
    """Spell a dotted path the way ``data`` spells its shorthands.

    A path through a shorthand reaches the same field whichever spelling ``data`` uses:
    ``road.demand.scale`` is ``backends.road.params.demand.scale`` when the data has no ``road:``
    key but a ``backends.road`` entry, and the other way round.
    """
    if not isinstance(data, dict):
        return keys
    if keys[:1] and keys[0] in SHORTHANDS and keys[0] not in data:
        backends = data.get("backends")
        if isinstance(backends, dict) and keys[0] in backends:
            return ["backends", keys[0], "params", *keys[1:]]
    if len(keys) >= 3 and keys[0] == "backends" and keys[1] in SHORTHANDS and keys[2] == "params" \
            and isinstance(data.get(keys[1]), dict):
        return [keys[1], *keys[3:]]
    return keys


def canonical_path(dotted: str) -> str:
    """The full spelling of an override path (``road.x`` -> ``backends.road.params.x``)."""
    keys = dotted.split(".")
    return ".".join(["backends", keys[0], "params", *keys[1:]]) if keys[0] in SHORTHANDS else dotted


def expand_shorthands(data: dict[str, Any], source: str) -> tuple[dict[str, Any], set[str]]:
    """Rewrite ``road: X`` as ``backends.road = {type: sumo, params: X}``, first among the backends.

    The backends' order is the order components are built and stepped in.

    Returns:
        The data and the names of the backend entries that came from a shorthand (their errors are
        reported in the shorthand).
    """
    if not any(k in data for k in SHORTHANDS):
        return data, set()
    data = dict(data)
    front: dict[str, Any] = {}
    for key, kind in SHORTHANDS.items():
        if key not in data:
            continue
        value = data.pop(key)
        if value is None:  # `road: null` (e.g. a variant removing the road): no such backend
            continue
        backends = data.get("backends")
        if isinstance(backends, dict) and key in backends:
            raise ScenarioError(f"{source}: {key}: is the shorthand of backends.{key}, which is given too; "
                                "use one of them")
        front[key] = {"type": kind, "params": value}
    backends = data.get("backends")
    data["backends"] = {**front, **backends} if isinstance(backends, dict) else (front if backends is None
                                                                                  else backends)
    return data, set(front)


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``data`` with every ``dotted.path: value`` of ``overrides`` set (``--set``, variants, draws)."""
    out = copy.deepcopy(data)
    for dotted, value in overrides.items():
        set_path(out, dotted, value)
    return out


def load_raw(path: str | Path, sets: list[str] | None = None) -> dict[str, Any]:
    """Read a scenario file with ``extends`` resolved and ``--set a.b=c`` applied (not validated)."""
    data = resolve_extends(Path(path))
    for item in sets or []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ScenarioError(f"--set {clip(item)}: expected FIELD.PATH=VALUE")
        set_path(data, key.strip(), parse_value(value))
        _unrandomize(data, key.strip())
    return data


def _unrandomize(data: dict[str, Any], key: str) -> None:
    """Take a field the user ``--set`` (and the fields beneath it) out of ``randomize``.

    Otherwise every run of the batch would silently replace the set value with a draw.
    """
    rnd = data.get("randomize")
    if key.startswith("randomize.") or not isinstance(rnd, dict):
        return
    key = canonical_path(key)  # road.x and backends.road.params.x are one field
    for path in [p for p in rnd if canonical_path(p) == key or canonical_path(p).startswith(key + ".")]:
        del rnd[path]


def set_overrides(sets: Sequence[str]) -> dict[str, Any]:
    """The ``--set`` values as overrides applied after a run's sweep variant.

    The command line wins over a variant that sets the same field (``sweep.`` and ``randomize.``
    paths are not re-applied: they edit the variants and draws themselves).
    """
    out: dict[str, Any] = {}
    for item in sets:
        key, _, value = item.partition("=")
        key = key.strip()
        if key.split(".")[0] not in ("sweep", "randomize"):
            out[key] = parse_value(value)
    return out
