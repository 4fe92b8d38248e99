"""Hybrid-automaton modes (after CHARON): named modes, guarded transitions with resets.

A controller that switches behaviour owns a ``HybridAutomaton``; each ``update`` evaluates the guards
of the current mode in declaration order and takes the first that holds.  Every transition is an
event in the run's event log, so reports and the Rerun timeline show *why* behaviour changed.

    ha = HybridAutomaton("ego", ["follow", "pass"], initial="follow", transitions=[
        Transition("follow", "pass", guard=lambda x: x["gap_ok"], label="gap found"),
        Transition("pass", "follow", guard=lambda x: x["done"], label="passed"),
    ])
    mode = ha.update(t, x, events)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from corridor.events import EventLog

Guard = Callable[[Any], bool]
Reset = Callable[[Any], Any]


@dataclass(frozen=True)
class Transition:
    """A guarded jump ``src`` -> ``dst``, taken when ``guard(state)`` holds; ``reset`` maps the state."""

    src: str
    dst: str
    guard: Guard
    label: str = ""
    reset: Reset | None = None  # maps the controller's continuous state on the jump


class HybridAutomaton:
    """A finite set of modes with guarded transitions; records each jump as an event."""

    def __init__(self, name: str, modes: Iterable[str], initial: str,
                 transitions: Sequence[Transition]) -> None:
        self.name = name
        self.modes = tuple(modes)
        if initial not in self.modes:
            raise ValueError(f"{name}: initial mode {initial!r} not in {self.modes}")
        for tr in transitions:
            for m in (tr.src, tr.dst):
                if m not in self.modes:
                    raise ValueError(f"{name}: transition {tr.src}->{tr.dst} names unknown mode {m!r}")
        self.initial = initial
        self._out: dict[str, list[Transition]] = {m: [] for m in self.modes}
        for tr in transitions:
            self._out[tr.src].append(tr)
        self.mode = initial
        self.entered_t = 0.0
        self.history: list[tuple[float, str, str, str]] = []  # (t, src, dst, label)

    def reset(self, t: float = 0.0) -> None:
        """Back to the initial mode at time ``t`` [s], with an empty history."""
        self.mode, self.entered_t, self.history = self.initial, t, []

    def time_in_mode(self, t: float) -> float:
        """Seconds spent in the current mode at time ``t`` [s]."""
        return t - self.entered_t

    def update(self, t: float, x: Any, events: EventLog | None = None) -> tuple[str, Any]:
        """Take at most one transition whose guard holds; return (mode, possibly reset state)."""
        for tr in self._out[self.mode]:
            if tr.guard(x):
                self.history.append((t, tr.src, tr.dst, tr.label))
                if events is not None:
                    events.emit(t, self.name, "mode", f"{tr.src} -> {tr.dst}: {tr.label}",
                                src=tr.src, dst=tr.dst)
                self.mode, self.entered_t = tr.dst, t
                return self.mode, (tr.reset(x) if tr.reset else x)
        return self.mode, x
