"""One mechanism for every entry-point group corridor reads, as pytest, Gymnasium and BlueSky plug-ins do.

corridor finds its pieces by name in the metadata of the installed distributions: components
(``corridor.components``), batch reports (``corridor.reports``), report sections
(``corridor.report_sections``), rare-event methods (``corridor.estimators``) and network builders
(``corridor.networks``).  A plug-in package declares its own entries in the same groups, without
editing corridor.  Every group is read the same way by a :class:`Registry`:

- the declarations are read once per group; one name declared twice with different targets (two
  distributions, or a plug-in and corridor) is an error naming both (:class:`DuplicateEntry`),
  never a silent shadowing;
- a target (``module:Attr``, or a module) is imported only when it is asked for (lazy), so a scenario
  that does not use JSBSim never imports it;
- an unknown name is one line listing the known ones (:class:`UnknownName`:
  ``unknown controller 'x'; known: a, b``).

Both errors are :class:`corridor.errors.CorridorError`: the command line prints them as one line
(exit code 2).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from typing import Any

from corridor.errors import CorridorError, clip


class EntryPointError(CorridorError, ValueError):
    """The installed entry points of a group are inconsistent (the message names them)."""


class DuplicateEntry(EntryPointError):
    """One name of an entry-point group is declared twice with different targets."""


class UnknownName(CorridorError, KeyError):
    """A name no entry point (and no registration in code) declares; the message lists the known ones."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True)
class Entry:
    """One declared entry: its name and where it lives (``"package.module:Attr"``, or a module)."""

    name: str
    entry_point: str  # "package.module:Attr", or "package.module" (the module itself)

    def load(self) -> Any:
        """Import the module and return the attribute (the module itself when none is named)."""
        module, _, attr = self.entry_point.partition(":")
        obj: Any = importlib.import_module(module.strip())
        for part in attr.strip().split(".") if attr.strip() else ():
            obj = getattr(obj, part)
        return obj


@cache
def declared(group: str) -> dict[str, str]:
    """Every installed entry point of ``group``, as name -> target (read once per process).

    Raises:
        DuplicateEntry: one name declared twice with different targets.
    """
    out: dict[str, str] = {}
    for ep in entry_points(group=group):
        if out.setdefault(ep.name, ep.value) != ep.value:
            a, b = sorted(clip(v, 80)[1:-1] for v in (out[ep.name], ep.value))  # whatever the path order
            raise DuplicateEntry(f"{group}: {clip(ep.name)} is declared twice ({a} and {b}); uninstall one of "
                                 "the packages that declare it")
    return out


class Registry:
    """A named table of lazily imported entries: one entry-point group, or one kind within a group.

    Args:
        what: what an entry is, for messages (``controller``, ``report section``).
        group: the entry-point group.
        prefix: only the group's names that start with it, without it (``controller.`` in
            ``corridor.components``); empty for the whole group.
    """

    def __init__(self, what: str, group: str, prefix: str = "") -> None:
        self.what = what
        self.group = group
        self.prefix = prefix
        self._entries: dict[str, Entry] = {}  # registered in code (tests, a builder registering itself)

    def _all(self) -> dict[str, Entry]:
        n = len(self.prefix)
        found = {k[n:]: Entry(k[n:], v) for k, v in declared(self.group).items() if k.startswith(self.prefix)}
        return {**found, **self._entries}

    def register(self, name: str, entry_point: str) -> None:
        """Add ``name`` -> ``entry_point`` in code.

        Raises:
            DuplicateEntry: ``name`` is known with another target.
        """
        known = self._all().get(name)
        if known is not None and known.entry_point != entry_point:
            raise DuplicateEntry(f"{self.what} {name!r} is already registered ({known.entry_point})")
        self._entries[name] = Entry(name, entry_point)

    def get(self, name: str) -> Any:
        """Import and return the target registered as ``name``.

        Raises:
            UnknownName: no such name (the message lists the known ones).
        """
        entry = self._all().get(name)
        if entry is None:
            raise self.unknown(name)
        return entry.load()

    def unknown(self, name: str, known: list[str] | None = None) -> UnknownName:
        """The error for a name that is not in the table: ``unknown <what> 'x'; known: a, b``."""
        names = ", ".join(sorted(self) if known is None else known)
        return UnknownName(f"unknown {self.what} {clip(name)}; known: {names or 'none installed'}")

    def names(self) -> list[str]:
        """Every name, sorted."""
        return sorted(self._all())

    def __contains__(self, name: object) -> bool:
        return name in self._all()

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())
