"""The metric glossary: what each result column means, its unit and which component writes it,
read from the components' own declarations (``Component.metrics``, a tuple of ``Metric``).

The report shows the glossary of the columns a batch has (``glossary_section``) and counts the
columns declared as safety events in its verdict (``safety_event_columns``); ``glossary_markdown``
writes the reference page of every installed component (``python -m corridor.analysis.glossary
docs/reference/metrics.md``).
"""

from __future__ import annotations

import fnmatch
import html
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from corridor.engine import Metric

Declared = list[tuple[str, Metric]]  # (component "<kind>.<type>", its metric)

TABLES = (("backends", "backend"), ("controllers", "controller"), ("monitors", "monitor"))
KERNEL_METRICS = (  # written by the batch runner for every run
    Metric("wall_s", "s", "Wall-clock time of the run."),
    Metric("sim_s", "s", "Simulated time of the run."),
    Metric("events_mode", "1", "Mode transitions of the controllers' automata (event log)."),
    Metric("events_fallback", "1", "Fallbacks to a safe mode (event log)."),
)


def _classes(scenario: Any) -> list[tuple[str, Any]]:
    """(``<kind>.<type>``, class) of every component a run of some variant of ``scenario`` builds:
    its backends, controllers (not ``none``), monitors, the default ones and those a backend requires."""
    from corridor.run import DEFAULT_MONITORS, SPEC_MONITOR
    from corridor.variants import component_class, variant_scenarios

    scens = [s for s in variant_scenarios(scenario).values() if s is not None] or [scenario]
    out: dict[str, Any] = {}
    for sc in scens:
        specs = [(t, spec) for t, _ in TABLES for spec in getattr(sc, t, {}).values()]
        specs += [("monitors", spec) for spec in DEFAULT_MONITORS.values()]
        specs += [("monitors", SPEC_MONITOR[1])] if getattr(sc, "specs", None) else []
        for table, spec in list(specs):
            cls = component_class(table, spec)
            for mon in getattr(cls, "required_monitors", {}).values():
                specs.append(("monitors", type(spec)(type=mon)))
        for table, spec in specs:
            if table == "controllers" and spec.type == "none":
                continue
            cls = component_class(table, spec)
            if cls is not None:
                out.setdefault(f"{dict(TABLES)[table]}.{spec.type}", cls)
    return list(out.items())


def declared_metrics(scenario: Any) -> Declared:
    """Every metric declared by a component of the scenario (any variant), the specs' and the kernel's."""
    out: Declared = [(label, m) for label, cls in _classes(scenario) for m in getattr(cls, "metrics", None) or ()]
    return out + [("batch", m) for m in KERNEL_METRICS]


def match(columns: Iterable[str], declared: Declared) -> dict[str, tuple[str, Metric]]:
    """column -> (component, metric) for the columns some declaration names (exact names first)."""
    out: dict[str, tuple[str, Metric]] = {}
    for c in columns:
        exact = [d for d in declared if d[1].name == c]
        hits = exact or [d for d in declared if "*" in d[1].name and fnmatch.fnmatchcase(c, d[1].name)]
        if hits:
            out[c] = hits[0]
    return out


def safety_event_columns(columns: Iterable[str], scenario: Any) -> list[str]:
    """The columns that count safety events (declared ``safety_event``) among ``columns``."""
    return [c for c, (_, m) in match(columns, declared_metrics(scenario)).items() if m.safety_event]


def units_of(columns: Iterable[str], scenario: Any) -> dict[str, str]:
    """column -> its declared unit (columns no component declares are left out)."""
    return {c: m.unit for c, (_, m) in match(columns, declared_metrics(scenario)).items()}


def glossary_section(columns: Iterable[str], scenario: Any) -> str:
    """An HTML table: column, meaning, unit, component, for the batch's columns (undeclared ones say so)."""
    cols = list(columns)
    known = match(cols, declared_metrics(scenario))
    rows = []
    for c in cols:
        label, m = known.get(c, ("–", None))
        meaning = m.meaning if m else "(not declared by its component)"
        unit = m.unit if m else "–"
        event = " <small>(safety event)</small>" if m is not None and m.safety_event else ""
        rows.append(f"<tr><td><code>{html.escape(c)}</code></td><td style='text-align:left'>"
                    f"{html.escape(meaning)}{event}</td><td>{html.escape(unit)}</td><td>{html.escape(label)}</td></tr>")
    return ("<section id=glossary><h2>Metric glossary</h2><p>Each column of this batch: what it measures, its unit (SI; 1: a "
            "count or a ratio) and the component that writes it, from the components' declarations.</p>"
            "<table><tr><th>column</th><th>meaning</th><th>unit</th><th>written by</th></tr>"
            + "".join(rows) + "</table></section>")


def _all_components() -> list[tuple[str, Any]]:
    from corridor.registry import BACKENDS, CONTROLLERS, MONITORS

    out = []
    for kind, reg in (("backend", BACKENDS), ("controller", CONTROLLERS), ("monitor", MONITORS)):
        for name in sorted(reg):
            try:
                out.append((f"{kind}.{name}", reg.get(name)))
            except Exception as exc:  # noqa: BLE001 - a component whose library is missing: say so
                out.append((f"{kind}.{name}", exc))
    return out


def _writes_columns(cls: Any) -> bool:
    """Whether a component class may write metric columns (it overrides ``finish``)."""
    from corridor.engine import Component

    return not isinstance(cls, Exception) and getattr(cls, "finish", None) is not Component.finish


def glossary_markdown() -> str:
    """The reference page: every installed component's declared metrics."""
    lines = ["# Metrics", "",
             "Generated by `python -m corridor.analysis.glossary docs/reference/metrics.md` from the "
             "components' declarations (`Component.metrics`); do not edit by hand.", "",
             "Units are SI with the unit's name; `1` is a count or a ratio. A *safety event* column counts "
             "events (a run with a value above 0 had one): the report's verdict counts every such column.", "",
             "| column | meaning | unit | written by |", "|---|---|---|---|"]
    silent = []
    for label, cls in _all_components():
        ms = getattr(cls, "metrics", None) if not isinstance(cls, Exception) else None
        if ms is None and _writes_columns(cls):
            silent.append(label)
        for m in ms or ():
            event = " (safety event)" if m.safety_event else ""
            lines.append(f"| `{m.name}` | {m.meaning}{event} | {m.unit} | `{label}` |")
    for label, m in [("batch", m) for m in KERNEL_METRICS]:
        lines.append(f"| `{m.name}` | {m.meaning} | {m.unit} | `{label}` |")
    if silent:
        lines += ["", "Components that write columns they do not declare yet (the report's glossary says so "
                  "for their columns): " + ", ".join(f"`{s}`" for s in silent) + "."]
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m corridor.analysis.glossary OUT.md", file=sys.stderr)
        return 2
    path = Path(args[0])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(glossary_markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
