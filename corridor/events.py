"""The run's event log: mode transitions, collisions, fallbacks — everything that explains a run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Event:
    """One event of a run: when [s], who raised it, its kind, a message and structured data."""

    t: float  # [s] simulation time
    source: str  # component or entity that raised it
    kind: str  # e.g. "mode", "collision", "fallback", "error"
    message: str
    data: dict[str, Any] = field(default_factory=dict)


class EventLog:
    """Append-only list of events with per-kind counters."""

    def __init__(self) -> None:
        self.events: list[Event] = []
        self.counts: dict[str, int] = {}

    def emit(self, t: float, source: str, kind: str, message: str, **data: Any) -> Event:
        """Record an event at time ``t`` [s] from ``source`` and return it (``data``: its structured fields)."""
        ev = Event(float(t), source, kind, message, data)
        self.events.append(ev)
        self.counts[kind] = self.counts.get(kind, 0) + 1
        return ev

    def of_kind(self, kind: str) -> list[Event]:
        """The events of one kind, in the order they were raised."""
        return [e for e in self.events if e.kind == kind]

    def __len__(self) -> int:
        return len(self.events)
