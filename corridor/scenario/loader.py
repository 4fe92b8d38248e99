"""Loading a scenario: read, resolve ``extends``, apply ``--set``, validate (components too).

``load`` is the entry point; every sweep variant and the edges of every ``randomize`` distribution
are validated at load, so a bad value is one line before any run starts.  ``resolve_scenario``
finds a packaged scenario by name.
"""

from __future__ import annotations

import difflib
import math
import re
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from corridor.errors import ScenarioError, clip
from corridor.scenario.files import scenario_dir
from corridor.scenario.messages import format_error, key_text, show_path
from corridor.scenario.overrides import apply_overrides, expand_shorthands, load_raw, set_overrides
from corridor.scenario.schema import Scenario


def _non_finite(data: Any, path: tuple[str, ...] = ()) -> tuple[str, ...] | None:
    """The path of the first NaN or infinite number anywhere in the raw data (component params too)."""
    if isinstance(data, float) and not math.isfinite(data):
        return path
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list | tuple) else ()
    for k, v in items:
        found = _non_finite(v, (*path, key_text(k)))
        if found is not None:
            return found
    return None


def validate(data: dict[str, Any], source: str) -> Scenario:
    """Validate raw scenario data, including each component's own ``params`` model."""
    source = show_path(source)
    bad = _non_finite(data)
    if bad is not None:
        raise ScenarioError(f"{source}: {'.'.join(bad)}: must be a finite number")
    data, shorthands = expand_shorthands(data, source)
    try:
        sc = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_error(source, exc, Scenario, shorthands=shorthands)) from None
    except RecursionError:
        raise ScenarioError(f"{source}: nested too deeply") from None
    _validate_component_params(sc, source, shorthands)
    return sc


def _validate_component_params(sc: Scenario, source: str, shorthands: set[str] | frozenset[str] = frozenset()) -> None:
    from corridor.registry import BACKENDS, CONTROLLERS, MONITORS

    for table, registry in (("backends", BACKENDS), ("controllers", CONTROLLERS), ("monitors", MONITORS)):
        for name, spec in getattr(sc, table).items():
            where = f"{table}.{key_text(name)}"
            if spec.type not in registry:
                close = difflib.get_close_matches(spec.type[:80], list(registry), n=1)
                known = ", ".join(sorted(registry))  # bounded: the message must stay one short line
                known = known if len(known) <= 120 else known[:known.rfind(", ", 0, 118)] + ", …"
                hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {known}"
                raise ScenarioError(f"{source}: {where}.type: unknown {registry.what} {clip(spec.type)}{hint}")
            cls = registry.get(spec.type)
            params_model = getattr(cls, "Params", None)
            params: Any = spec.params
            if params_model is not None:
                try:
                    params = params_model.model_validate(spec.params)
                except ValidationError as exc:
                    raise ScenarioError(format_error(source, exc, params_model, f"{where}.params",
                                                     shorthands if table == "backends" else frozenset())) from None
            _check_component(cls, params, sc, f"{source}: {where}")


def _check_component(cls: Any, params: Any, sc: Scenario, where: str) -> None:
    """Run a component's own load-time check of the scenario around it, if it has one.

    ``check_scenario(params, sc)`` is optional: a controller that needs landmarks the road's network
    does not have says so here.
    """
    check = getattr(cls, "check_scenario", None)
    if check is None:
        return
    try:
        check(params, sc)
    except ValueError as exc:
        raise ScenarioError(f"{where}: {str(exc).strip()}") from None


def check_randomize(sc: Scenario, data: dict[str, Any], source: str) -> None:
    """Check that each ``randomize`` path gives a valid scenario at the edges of its distribution.

    It must do so in at least one sweep variant that is valid by itself: a path or value no variant
    accepts is an error at load, not an error row in every run.
    """
    source = show_path(source)
    bases = [over for over in sc.sweep.values() if _is_valid(apply_overrides(data, over))]
    for path, dist in sorted(sc.randomize.items()):
        for value in dist.extremes():
            errors = []
            for over in bases:
                try:
                    validate(apply_overrides(data, {**over, path: value}), source)
                    break
                except ScenarioError as exc:
                    errors.append(str(exc).removeprefix(f"{source}: "))
            else:
                if errors:
                    raise ScenarioError(f"{source}: randomize.{clip(path, 60)[1:-1]}: the draw {clip(value, 30)} "
                                        f"is invalid: {errors[0]}")


def _is_valid(data: dict[str, Any]) -> bool:
    try:
        validate(data, "")
    except ScenarioError:
        return False
    return True


_COMPONENT_TABLES = ("backends", "controllers", "monitors")


def _variant_hint(path: str | Path, sets: list[str], message: str) -> str:
    """Say how to set a field that exists only inside a sweep variant.

    When a ``--set`` below a component fails on the base scenario but works inside a sweep variant
    (merging.yaml: ``controllers.merge`` is ``v2x_merging`` only in the v2x variants, so its params
    cannot be set on the base), the hint names the variant path to set instead.
    """
    for item in sets:
        key = item.partition("=")[0].strip()
        parts = key.split(".")
        if len(parts) < 3 or parts[0] not in _COMPONENT_TABLES or f"{parts[0]}.{parts[1]}" not in message:
            continue
        rest = [s for s in sets if s is not item]
        sweep = load_raw(path, rest).get("sweep")
        works = []
        for variant in list(sweep)[:8] if isinstance(sweep, dict) else []:
            try:
                data = load_raw(path, [*rest, f"sweep.{variant}.{item}"])
                validate(apply_overrides(data, data["sweep"][variant]), "")
            except ScenarioError:
                continue
            works.append(key_text(variant))
        if works:
            return (f"; {parts[0]}.{key_text(parts[1])} is set per variant: use --set sweep.VARIANT.{clip(key, 60)[1:-1]}"
                    f"=VALUE (works for {clip(', '.join(works), 50)[1:-1]})")
    return ""


def load(path: str | Path, sets: list[str] | None = None) -> tuple[Scenario, dict[str, Any]]:
    """Load, resolve, override and validate; returns the typed scenario and its raw data.

    Files the scenario names (``ScenarioFile`` fields) are relative to the scenario file's folder.
    """
    sc, data, _ = load_with_files(path, sets)
    return sc, data


def load_with_files(path: str | Path, sets: list[str] | None = None) -> tuple[Scenario, dict[str, Any], set[str]]:
    """``load``, and the files the scenario names (``ScenarioFile`` fields of the base scenario)."""
    data = load_raw(path, sets)
    with scenario_dir(Path(path).parent) as named:
        sc, data = _load_validated(path, data, sets)
    return sc, data, named


def _load_validated(path: str | Path, data: dict[str, Any], sets: list[str] | None) -> tuple[Scenario, dict[str, Any]]:
    try:
        sc = validate(data, str(path))
    except ScenarioError as exc:
        hint = _variant_hint(path, sets or [], str(exc))
        if not hint:
            raise
        raise ScenarioError(re.sub("; allowed: .*", "", str(exc)) + hint) from None
    after = set_overrides(sets or [])
    for variant, over in sc.sweep.items():  # every variant is checked now, not in every run of the batch
        if over:
            validate(apply_overrides(data, {**over, **after}), f"{path} [sweep.{key_text(variant)}]")
    check_randomize(sc, data, str(path))
    return sc, data


def resolve_scenario(name: str) -> Path:
    """The scenario file a name stands for.

    An existing path (or a name ending in ``.yaml``) is kept as it is; a bare name is a packaged
    scenario (``merging`` -> ``scenarios/merging.yaml``).

    Raises:
        ScenarioError: neither a file nor a packaged scenario (the packaged names are listed).
    """
    path = Path(name)
    try:
        exists = path.exists()
    except OSError:  # e.g. a name too long for the file system
        exists = False
    if exists or path.suffix in (".yaml", ".yml"):
        return path
    dirs = [Path(__file__).resolve().parents[2] / "scenarios"]  # the repository's scenarios/ (a clone)
    try:
        import corridor.scenarios as pkg  # installed wheel: scenarios ship as package data

        dirs += [Path(p) for p in pkg.__path__]
    except ImportError:
        pass
    if len(name) <= 64 and name.replace("_", "").replace("-", "").isalnum():  # a bare name, not a path
        for d in dirs:
            if (d / f"{name}.yaml").is_file():
                return d / f"{name}.yaml"
    names = sorted({p.stem for d in dirs if d.is_dir() for p in d.glob("*.yaml")})
    raise ScenarioError(f"{clip(name)}: no such file, and no packaged scenario of that name "
                        f"(packaged: {', '.join(names)})")
