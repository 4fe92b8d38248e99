"""Register components by name through Python entry points, as pytest, Gymnasium and BlueSky plug-ins do.

A scenario says ``type: alinea`` and the registry finds the class.

Every component is an entry point of the group ``corridor.components`` named ``<kind>.<type>``
(``backend.sumo``, ``controller.ramp_alinea``, ``monitor.collisions``, ``recorder.rerun``) whose value
is ``module:Class``.  corridor declares its own in ``pyproject.toml``; a user's package adds a
controller, monitor or backend by declaring one in its own metadata, without editing corridor.
Entries are read from the installed distributions' metadata once, and a class is imported only
when a scenario uses it, so loading a scenario does not import CasADi or JSBSim unless it needs them.
The mechanism (duplicate check, lazy import, "unknown X; known: ..." errors) is
:mod:`corridor.entrypoints`, shared by every entry-point group.
"""

from __future__ import annotations

from functools import cache

from corridor.entrypoints import DuplicateEntry, Entry, EntryPointError, Registry, UnknownName, declared

GROUP = "corridor.components"

__all__ = ["BACKENDS", "CONTROLLERS", "GROUP", "MONITORS", "RECORDERS", "ComponentRegistry", "DuplicateEntry",
           "Entry", "EntryPointError", "Registry", "UnknownName"]


@cache
def _check_names() -> None:
    """Every ``corridor.components`` entry point is named ``<kind>.<type>`` (read once)."""
    for name in declared(GROUP):
        kind, dot, rest = name.partition(".")
        if not dot or not kind or not rest:
            raise EntryPointError(f"{GROUP} entry point {name!r}: expected '<kind>.<name>', e.g. controller.alinea")


class ComponentRegistry(Registry):
    """The components of one kind: the ``corridor.components`` entry points named ``<kind>.<type>``.

    Plus any registered in code (tests).  An unknown type is an :class:`UnknownName` (a ``KeyError``)
    listing the known ones; one type declared twice differently is a :class:`DuplicateEntry`.
    """

    def __init__(self, what: str) -> None:
        super().__init__(what, GROUP, prefix=f"{what}.")

    def _all(self) -> dict[str, Entry]:
        _check_names()
        return super()._all()


# The component tables.  Each entry point is a class with a nested pydantic ``Params`` model
# (validated at scenario load) and a constructor ``cls(name, params, scenario)``.
BACKENDS = ComponentRegistry("backend")
CONTROLLERS = ComponentRegistry("controller")
MONITORS = ComponentRegistry("monitor")
RECORDERS = ComponentRegistry("recorder")  # cls(name, scenario, path): record a run to a file (Rerun)
