"""Error formatting of the scenario loader: one line naming the file and the field path.

``format_error`` turns the first pydantic validation error into
``scenarios/x.yaml: road.demand.flows.ramp.flow_vph: must be >= 0`` with a "did you mean" hint for an
unknown key and the field's unit for a bound.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from corridor.errors import clip
from corridor.scenario.schema import SHORTHANDS, Scenario


def key_text(name: Any) -> str:
    """A user-chosen key inside a field path: as is when short and printable, else clipped."""
    text = str(name)
    return text if len(text) <= 40 and text.isprintable() else clip(text, 40)




class NestedParamsError(ValueError):
    """A nested params mapping failed its own model.

    Raised by a component's params validator that checked a free-form mapping (``where``, e.g.
    ``params`` of a network) against another model: the loader reports the inner field's path
    (``road.network.params.lanes: must be >= 1``) and the hints of ``model``.
    """

    def __init__(self, where: str, error: ValidationError, model: type[BaseModel]) -> None:
        super().__init__(str(error).splitlines()[0])
        self.where, self.error, self.model = where, error, model


def show_path(path: Path | str) -> str:
    """A path for an error message: as is when short and printable, else clipped (one line)."""
    text = str(path)
    return text if len(text) <= 120 and text.isprintable() else clip(text, 120)


def _field_names(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The field names allowed at ``loc`` (for "did you mean" hints)."""
    cur: Any = model
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is None or part not in fields:
            return []
        ann = fields[part].annotation
        cur = _model_in(ann)
        if cur is None:
            return []
    return list(getattr(cur, "model_fields", {}))


def _model_in(ann: Any) -> Any:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        m = _model_in(arg)
        if m is not None:
            return m
    return None


def _unit(model: type[BaseModel], loc: tuple[Any, ...]) -> str:
    """The ``unit`` a field declares (``json_schema_extra``), for bound messages."""
    cur: Any = model
    info = None
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is None or part not in fields:
            continue
        info = fields[part]
        cur = _model_in(info.annotation)
    extra = getattr(info, "json_schema_extra", None)
    return f" {extra['unit']}" if isinstance(extra, dict) and "unit" in extra else ""


def format_error(source: str, exc: ValidationError, model: type[BaseModel], prefix: str = "",
                 shorthands: set[str] | frozenset[str] = frozenset()) -> str:
    """The first validation error as ``FILE: field.path: message (did you mean 'x'?)``.

    Paths into backend entries named in ``shorthands`` are shown as the shorthand spelled them
    (``road.x``).
    """
    err = exc.errors()[0]
    loc = tuple(err["loc"])
    nested = (err.get("ctx") or {}).get("error")
    if err["type"] == "value_error" and isinstance(nested, NestedParamsError):
        inner = ".".join(key_text(p) for p in (*loc, nested.where))
        return format_error(source, nested.error, nested.model, f"{prefix}.{inner}" if prefix else inner,
                            shorthands)
    path = ".".join(key_text(p) for p in loc)
    path = f"{prefix}.{path}" if prefix and path else (prefix or path)
    for name in shorthands:
        full = f"backends.{name}.params"
        if path == full or path.startswith(full + "."):
            path = name + path[len(full):]
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        allowed = _field_names(model, _model_path(model, loc[:-1]))
        if model is Scenario and len(loc) == 1:
            allowed += list(SHORTHANDS)
        close = difflib.get_close_matches(str(loc[-1])[:80], allowed, n=1)
        listed = ", ".join(allowed)
        listed = listed if len(listed) <= 120 else listed[:listed.rfind(", ", 0, 118)] + ", …"
        msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close else (f"; allowed: {listed}" if allowed else ""))
    elif err["type"] in ("greater_than_equal", "greater_than", "less_than_equal", "less_than"):
        msg = msg.replace("Input should be", "must be") + _unit(model, loc)
    elif err["type"] == "finite_number":
        msg = "must be a finite number"
    elif msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    msg = msg if len(msg) <= 240 else msg[:239] + "…"
    n = len(exc.errors())
    more = f" (+{n - 1} more)" if n > 1 else ""
    return f"{source}: {path}: {msg}{more}" if path else f"{source}: {msg}{more}"


def _model_path(model: type[BaseModel], loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """Drop dict keys / list indices from a location so it walks model fields only."""
    out: list[Any] = []
    cur: Any = model
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is not None and part in fields:
            out.append(part)
            cur = _model_in(fields[part].annotation)
    return tuple(out)
