"""Register components by name through Python entry points, as pytest, Gymnasium and BlueSky plug-ins do.

A scenario says ``type: alinea`` and the registry finds the class.

Every component is an entry point of the group ``corridor.components`` named ``<kind>.<type>``
(``backend.sumo``, ``controller.ramp_alinea``, ``monitor.collisions``, ``recorder.rerun``) whose value
is ``module:Class``.  corridor declares its own in ``pyproject.toml``; a user's package adds a
controller, monitor or backend by declaring one in its own metadata, without editing corridor.
Entries are read from the installed distributions' metadata once, and a class is imported only
when a scenario uses it, so loading a scenario does not import CasADi or JSBSim unless it needs them.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from typing import Any

GROUP = "corridor.components"


@dataclass(frozen=True)
class Entry:
    """One declared component: its type name and where it lives (``"package.module:Attr"``)."""

    name: str
    entry_point: str  # "package.module:Attr"

    def load(self) -> Any:
        """Import the module and return the attribute (the component class)."""
        module, _, attr = self.entry_point.partition(":")
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj


@cache
def _declared() -> dict[str, dict[str, str]]:
    """Every installed ``corridor.components`` entry point, as kind -> {type name -> "module:Attr"}.

    Two distributions declaring one name differently is an error (no silent shadowing).
    """
    out: dict[str, dict[str, str]] = {}
    for ep in entry_points(group=GROUP):
        kind, dot, name = ep.name.partition(".")
        if not dot or not name:
            raise ValueError(f"{GROUP} entry point {ep.name!r}: expected '<kind>.<name>', e.g. controller.alinea")
        table = out.setdefault(kind, {})
        if table.get(name, ep.value) != ep.value:
            raise ValueError(f"{GROUP}: {kind} {name!r} is declared twice ({table[name]} and {ep.value})")
        table[name] = ep.value
    return out


class Registry:
    """A named table of lazily imported entry points of one kind.

    It holds those declared under ``<kind>.`` in the ``corridor.components`` group, plus any
    registered in code (tests).
    """

    def __init__(self, what: str) -> None:
        self.what = what  # the kind: backend, controller, monitor, recorder
        self._entries: dict[str, Entry] = {}

    def _all(self) -> dict[str, Entry]:
        declared = {n: Entry(n, v) for n, v in _declared().get(self.what, {}).items()}
        return {**declared, **self._entries}

    def register(self, name: str, entry_point: str) -> None:
        """Add ``name`` -> ``entry_point`` (``"module:Class"``) in code; another target for a known name is a ValueError."""
        known = self._all().get(name)
        if known is not None and known.entry_point != entry_point:
            raise ValueError(f"{self.what} {name!r} is already registered")
        self._entries[name] = Entry(name, entry_point)

    def get(self, name: str) -> Any:
        """Import and return the class registered as ``name``; an unknown name is a KeyError listing the known ones."""
        try:
            entry = self._all()[name]
        except KeyError:
            raise KeyError(f"unknown {self.what} {name!r}; known: {', '.join(sorted(self))}") from None
        return entry.load()

    def __contains__(self, name: object) -> bool:
        return name in self._all()

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())


# The component tables.  Each entry point is a class with a nested pydantic ``Params`` model
# (validated at scenario load) and a constructor ``cls(name, params, scenario)``.
BACKENDS = Registry("backend")
CONTROLLERS = Registry("controller")
MONITORS = Registry("monitor")
RECORDERS = Registry("recorder")  # cls(name, scenario, path): record a run to a file (Rerun)
