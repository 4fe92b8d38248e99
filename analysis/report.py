"""The HTML report of a batch: self-contained (matplotlib charts as inline SVG, ``corridor.analysis.plots``),
read from the results table.  Its contents are described in docs/guide/reports.md.

The report shows only what applies to the scenario and to each variant:

- **Collisions.** The collision section (and collisions among the "problem runs") appears only when
  some variant has entities a collision monitor can see: a road (SUMO vehicles) or a backend that
  contributes rows to the world snapshot (its class overrides ``Backend.snapshot_part``: aircraft,
  the ego).  A macroscopic model (METANET) has no vehicles, so its runs' ``collisions = 0`` is no
  evidence of safety and no collision probability is shown.  A run that did report a collision
  always keeps the section.
- **Sensitivities.** Each variant is validated on its own (the base scenario with that variant's
  sweep overrides, as a run does), and a randomized field is fitted for a variant only if that
  variant uses it (``draw_not_applicable``): ``channels.<c>`` only if one of its components
  references channel ``<c>`` (a ``channel`` parameter, defaults included); ``controllers|backends|
  monitors.<n>...`` only if component ``<n>`` exists and runs (a controller of type ``none`` does
  not), and ``...params.<field>`` only if the component's ``Params`` has ``<field>`` and ``<field>``
  does not configure another component type (the ``control_tube`` section of an avoidance
  controller that runs ``potential_field``); ``road.*`` only if the variant has a road.  The rule is
  structural: a field a component reads counts, even where reading it changes nothing.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import linregress
from scipy.stats import t as student_t

from corridor.analysis.glossary import glossary_section, safety_event_columns, units_of
from corridor.analysis.plots import box_or_points, figure, svg
from corridor.analysis.stats import clopper_pearson, mean_ci
from corridor.reports import report_sections
from corridor.traffic.sumo.road_spec import road_spec
from corridor.variants import collisions_apply, has_entities, variant_scenarios
from corridor.variants import component_class as _component_class
from corridor.variants import registries as _registries

__all__ = ["collisions_apply", "has_entities", "variant_scenarios", "write_report", "write_batch_report"]

CSS = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}.bad{color:#b00}.good{color:#070}
img{max-width:100%}code{background:#f3f3f3;padding:1px 3px}.res{font-weight:bold}"""

MIN_BOX = 5  # runs of a variant below which its distribution is drawn as points, not a box
NON_METRICS = {"run_id", "scenario", "variant", "seed", "status", "error", "traceback"}


ENTITY_FREE_REASON = "no vehicles: none of its backends puts entities in the world snapshot"


def _channel_refs(value: Any, key: str = "") -> set[str]:
    """Channel names referenced in (dumped) component parameters: values of keys named ``channel``,
    ``channels`` or ``*_channel``, at any depth."""
    out: set[str] = set()
    if isinstance(value, dict):
        for k, x in value.items():
            out |= _channel_refs(x, str(k))
    elif isinstance(value, list | tuple | set):
        for x in value:
            out |= _channel_refs(x, key)
    elif isinstance(value, str) and (key in ("channel", "channels") or key.endswith("_channel")):
        out.add(value)
    return out


def _params_dump(table: str, spec: Any) -> dict[str, Any]:
    cls = _component_class(table, spec)
    model = getattr(cls, "Params", None)
    try:
        return model.model_validate(spec.params).model_dump() if model is not None else dict(spec.params)
    except Exception:  # noqa: BLE001 - a variant that would fail its run: use the raw params
        return dict(spec.params)


def _running(vsc: Any) -> list[tuple[str, str, Any]]:
    """(table, name, spec) of every component a run of this variant builds (a ``none`` controller
    is not built)."""
    return [(t, n, spec) for t in ("backends", "controllers", "monitors")
            for n, spec in getattr(vsc, t).items() if not (t == "controllers" and spec.type == "none")]


def channels_used(vsc: Any) -> set[str]:
    """The channels some running component of a variant's scenario references."""
    return set().union(*(_channel_refs(_params_dump(t, spec)) for t, _, spec in _running(vsc)))


def draw_not_applicable(vsc: Any, path: str) -> str | None:
    """Why the randomized field ``path`` cannot affect a variant (its validated scenario ``vsc``), or
    None if it may.  The rule is the module docstring's."""
    if vsc is None:
        return None
    parts = path.split(".")
    head = parts[0]
    if head == "channels" and len(parts) > 1:
        return None if parts[1] in channels_used(vsc) else f"no component uses channel {parts[1]}"
    if head == "road":
        return None if road_spec(vsc) is not None else "no road"
    if head in ("controllers", "backends", "monitors") and len(parts) > 1:
        spec = getattr(vsc, head).get(parts[1])
        if spec is None:
            return f"no {head[:-1]} {parts[1]}"
        if head == "controllers" and spec.type == "none":
            return f"controller {parts[1]} is of type none"
        if len(parts) > 3 and parts[2] == "params":
            cls = _component_class(head, spec)
            model = getattr(cls, "Params", None)
            if cls is not None and model is None:
                return f"{spec.type} takes no parameters"
            fields = getattr(model, "model_fields", None)
            extra = (getattr(model, "model_config", {}) or {}).get("extra") == "allow"
            if fields is not None and parts[3] not in fields and not extra:
                return f"{spec.type} has no parameter {parts[3]}"
            if parts[3] != spec.type and parts[3] in _registries()[head]:
                return f"the {parts[3]} section configures another {head[:-1]} type ({parts[1]} runs {spec.type})"
    return None


def not_applicable_draws(ok: pd.DataFrame, scenario: Any) -> dict[str, dict[str, str]]:
    """variant -> {draw column -> why it does not apply} for the randomized columns of ``ok``."""
    scen = variant_scenarios(scenario)
    draws = [c for c in ok.columns if c.startswith("draw.")]
    out: dict[str, dict[str, str]] = {}
    for v in dict.fromkeys(ok["variant"].astype(str)) if "variant" in ok else []:
        why = {c: r for c in draws if (r := draw_not_applicable(scen.get(v), c[5:])) is not None}
        if why:
            out[v] = why
    return out


def _num(x: float | None, digits: int = 3) -> str:
    """A value for a table cell: "—" when it is missing or not finite (never "nan")."""
    try:
        ok = x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        return "—"
    v = float(x)
    if v == 0 or 1e-3 <= abs(v) < 1e6:  # plain digits (2320, not 2.32e+03)
        return np.format_float_positional(v, precision=digits, unique=False, fractional=False, trim="-")
    return f"{v:.{digits}g}"


def _interval(lo: float, hi: float) -> str:
    return f"[{_num(lo)}, {_num(hi)}]" if math.isfinite(lo) and math.isfinite(hi) else ""


def metric_columns(df: pd.DataFrame) -> list[str]:
    cols = []
    for c in df.columns:
        if c in NON_METRICS or c.startswith("draw."):
            continue
        if pd.api.types.is_numeric_dtype(df[c]) or pd.api.types.is_bool_dtype(df[c]):
            cols.append(c)
    return cols


def distribution_plot(ok: pd.DataFrame, column: str, title: str, unit: str = "") -> str:
    """Per variant: a box plot with its points, or the points alone below ``MIN_BOX`` runs."""
    groups = [(str(v), pd.to_numeric(g[column], errors="coerce").dropna().to_numpy(dtype=float))
              for v, g in ok.groupby("variant", sort=False)]
    groups = [(v, x[np.isfinite(x)]) for v, x in groups]
    groups = [(v, x) for v, x in groups if len(x)]
    if not groups:
        return ""
    return box_or_points(groups, title, f"{column} [{unit}]" if unit else column, MIN_BOX)


def _cell(x: np.ndarray, base_mean: float, is_base: bool) -> str:
    """Mean [95 % CI] of the finite values, their count when some are missing, % vs the baseline."""
    finite = np.isfinite(x)
    n, k = len(x), int(finite.sum())
    if not k:
        return f"<td>— <small>(no value in {n} run{'s' if n != 1 else ''})</small></td>"
    m, lo, hi = mean_ci(x)
    sd = float(np.std(x[finite], ddof=1)) if k > 1 else math.nan
    rel = ""
    if not is_base and math.isfinite(base_mean) and base_mean != 0:
        rel = f" <small>({(m - base_mean) / abs(base_mean) * 100:+.1f} %)</small>"
    ci = _interval(lo, hi)
    count = f" <small>n={k}</small>" if k == n else f" <small>n={k} of {n}</small>"
    return (f"<td title='sd {_num(sd, 2)}'>{_num(m)}{rel}"
            f"{f' <small>{ci}</small>' if ci else ''}{count}</td>")


def kpi_table(ok: pd.DataFrame, cols: list[str], baseline: str, units: dict[str, str] | None = None) -> str:
    """Per metric and variant: the mean, its 95 % Student-t interval and the number of runs with a
    value (missing values, e.g. no closing pair for a TTC, are counted, never averaged)."""
    units = units or {}
    variants = list(dict.fromkeys(ok["variant"]))
    head = "".join(f"<th>{html.escape(str(v))}</th>" for v in variants)
    base = ok[ok["variant"] == baseline]
    rows = []
    for c in cols:
        b = mean_ci(pd.to_numeric(base[c], errors="coerce").to_numpy(dtype=float))[0] if len(base) else math.nan
        cells = [_cell(pd.to_numeric(ok[ok["variant"] == v][c], errors="coerce").to_numpy(dtype=float), b,
                       v == baseline) for v in variants]
        unit = f" [{html.escape(units[c])}]" if units.get(c) else ""
        rows.append(f"<tr><td>{html.escape(c)}{unit}</td>{''.join(cells)}</tr>")
    return (f"<table><tr><th>metric [unit] (mean, % vs {html.escape(str(baseline))}, [95 % CI], runs with a value)"
            f"</th>{head}</tr>{''.join(rows)}</table>")


def _paired(ok: pd.DataFrame, column: str, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
    """One metric of ``a`` and of ``b`` over the seeds both variants ran, aligned by seed."""
    x = ok[ok["variant"] == a].set_index("seed")[column]
    y = ok[ok["variant"] == b].set_index("seed")[column]
    both = x.index.intersection(y.index)
    return (pd.to_numeric(x.loc[both], errors="coerce").to_numpy(dtype=float),
            pd.to_numeric(y.loc[both], errors="coerce").to_numpy(dtype=float))


def paired_differences(ok: pd.DataFrame, column: str, a: str, b: str) -> np.ndarray:
    """``a − b`` of one metric over the seeds both variants ran (the same draws: common random numbers)."""
    x, y = _paired(ok, column, a, b)
    return x - y


def paired_table(ok: pd.DataFrame, cols: list[str]) -> str:
    """Every pair of variants, per key metric: the mean paired difference with its 95 % Student-t
    interval.  Each seed gives every variant the same demand and draws, so the per-seed difference
    cancels most of the run-to-run spread that the per-variant means carry; an interval that
    excludes 0 is a difference the batch resolves, one that contains 0 is not (yet)."""
    variants = list(dict.fromkeys(ok["variant"]))
    pairs = [(a, b) for i, b in enumerate(variants) for a in variants[i + 1:]]
    if not pairs:
        return ""
    head = "".join(f"<th>{html.escape(a)} − {html.escape(b)}</th>" for a, b in pairs)
    rows = []
    for c in cols:
        cells = []
        for a, b in pairs:
            x, y = _paired(ok, c, a, b)
            d = x - y
            m, lo, hi = mean_ci(d)
            n = int(np.isfinite(d).sum())
            cls = "" if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0 <= hi else " class=res"
            ref = float(np.mean(y[np.isfinite(d)])) if n else math.nan
            rel = f" ({m / abs(ref) * 100:+.1f} %)" if math.isfinite(m) and math.isfinite(ref) and ref != 0 else ""
            if not n:
                cells.append("<td>— <small>(no seed with a value in both)</small></td>")
                continue
            ci = _interval(lo, hi)
            cells.append(f"<td{cls}>{_num(m)}{rel} <small>{ci + ', ' if ci else ''}n={n}</small></td>")
        rows.append(f"<tr><td>{html.escape(c)}</td>{''.join(cells)}</tr>")
    return ("<p>Mean paired difference per seed (in % of the second variant's mean over the same seeds),"
            " [95 % CI]; <b>bold</b>: the interval excludes 0.</p>"
            f"<table><tr><th>metric</th>{head}</tr>{''.join(rows)}</table>")


def _slope_ci(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares slope of y on x and its 95 % Student-t interval."""
    res = linregress(x, y)
    if len(x) < 3 or not math.isfinite(res.stderr):
        return float(res.slope), math.nan, math.nan
    h = float(student_t.ppf(0.975, len(x) - 2) * res.stderr)
    return float(res.slope), float(res.slope) - h, float(res.slope) + h


def draw_sensitivity(ok: pd.DataFrame, column: str, not_applicable: dict[str, dict[str, str]] | None = None,
                     unit: str = "") -> str:
    """The metric against each randomized field, per variant, with a least-squares line and its
    slope's 95 % interval: how the result moves with demand, penetration, message loss ... over the
    batch's draws.  A (variant, field) pair in ``not_applicable`` (variant -> {draw column -> reason})
    is neither drawn nor fitted; it is listed under the table with its reason."""
    skip = not_applicable or {}
    variants = list(dict.fromkeys(ok["variant"].astype(str))) if "variant" in ok else []
    draws = [c for c in ok.columns if c.startswith("draw.") and pd.api.types.is_numeric_dtype(ok[c])]
    draws = [c for c in draws if ok[c].nunique() > 2 and any(c not in skip.get(v, {}) for v in variants)]
    if not draws or column not in ok:
        return ""
    fig, axes = figure((min(3.2 * len(draws), 10.0) + 1.2, 3.0), ncols=len(draws), sharey=True)
    rows = []
    for ax, dc in zip(axes, draws, strict=True):
        for i, (v, g) in enumerate(ok.groupby("variant", sort=False)):
            if dc in skip.get(str(v), {}):
                continue
            x = g[dc].to_numpy(dtype=float)
            y = pd.to_numeric(g[column], errors="coerce").to_numpy(dtype=float)
            keep = np.isfinite(x) & np.isfinite(y)
            ax.plot(x[keep], y[keep], ".", color=f"C{i}", alpha=0.6, label=str(v) if dc == draws[0] else None,
                    gid=f"points:{v}:{dc}")
            if keep.sum() >= 3 and np.ptp(x[keep]) > 0:
                slope, lo, hi = _slope_ci(x[keep], y[keep])
                icpt = float(np.mean(y[keep]) - slope * np.mean(x[keep]))
                xs = np.array([x[keep].min(), x[keep].max()])
                ax.plot(xs, icpt + slope * xs, "-", color=f"C{i}", lw=1)
                span = float(np.ptp(x[keep]))
                rows.append(f"<tr><td>{html.escape(str(v))}</td><td>{html.escape(dc[5:])}</td>"
                            f"<td>{_num(slope)} <small>{_interval(lo, hi)}</small></td>"
                            f"<td>{_num(slope * span)} <small>{_interval(lo * span, hi * span)}</small></td>"
                            f"<td>{int(keep.sum())}</td></tr>")
        ax.set_xlabel(dc[5:], fontsize=8)
    axes[0].set_ylabel(f"{column} [{unit}]" if unit else column)
    axes[0].legend(fontsize=7)
    u = html.escape(unit) if unit else "its unit"
    table = (f"<table><tr><th>variant</th><th>randomized field</th><th>slope of {html.escape(column)} "
             f"[{u} per unit of the field] [95 % CI]</th><th>change of {html.escape(column)} over the drawn "
             f"range [{u}] [95 % CI]</th><th>runs</th></tr>" + "".join(rows) + "</table>")
    left_out = [f"<li>{html.escape(v)} &times; <code>{html.escape(dc[5:])}</code>: {html.escape(why)}</li>"
                for v in variants for dc, why in skip.get(v, {}).items() if dc in ok.columns]
    note = ("<p>Not fitted (the field cannot affect that variant):</p><ul>" + "".join(left_out) + "</ul>"
            if left_out else "")
    return svg(fig, "sensitivity") + table + note


def collision_table(df: pd.DataFrame) -> str:
    rows = []
    for v, g in df.groupby("variant", sort=False):
        ok = g[g["status"] == "ok"]
        coll = ok["collisions"].fillna(0) if "collisions" in ok else pd.Series(dtype=float)
        k, n = int((coll > 0).sum()), len(ok)
        lo, hi = clopper_pearson(k, n)
        cls = "bad" if k else "good"
        rows.append(f"<tr><td>{html.escape(str(v))}</td><td>{len(g)}</td><td>{len(g) - n}</td>"
                    f"<td class={cls}>{int(coll.sum())}</td><td class={cls}>{k}/{n}</td>"
                    f"<td>[{_num(lo)}, {_num(hi)}]</td></tr>")
    return ("<table><tr><th>variant</th><th>runs</th><th>errors</th><th>collisions</th>"
            "<th>runs with a collision</th><th>P(collision) 95 % exact CI</th></tr>" + "".join(rows) + "</table>")


def _events_of(r: pd.Series, event_cols: list[str], spec_cols: list[str]) -> list[str]:
    """What went wrong in one ok run: its safety events (``2 nmac``) and the specs it violated."""
    out = [f"{int(v)} {c}" for c in event_cols if (v := pd.to_numeric(r.get(c), errors="coerce")) > 0]
    violated = [c.split(".")[1] for c in spec_cols if r.get(c) is False or r.get(c) == 0]
    return out + ([f"violates {', '.join(violated)}"] if violated else [])


def safety_verdict(df: pd.DataFrame, event_cols: list[str]) -> str:
    """Per variant: runs with each safety event (``k/n``, total count), runs violating a spec, errors.
    Green only where every count is 0."""
    spec_cols = [c for c in df.columns if c.startswith("spec.") and c.endswith(".satisfied")]
    head = "".join(f"<th>runs with {html.escape(c)} (total)</th>" for c in event_cols)
    rows = []
    for v, g in df.groupby("variant", sort=False):
        ok = g[g["status"] == "ok"]
        cells = []
        for c in event_cols:
            x = pd.to_numeric(ok[c], errors="coerce").fillna(0)
            k = int((x > 0).sum())
            cells.append(f"<td class={'bad' if k else 'good'}>{k}/{len(ok)} ({int(x.sum())})</td>")
        sv = int(sum(((ok[c] == False) | (ok[c] == 0)).sum() for c in spec_cols))  # noqa: E712
        spec = f"<td class={'bad' if sv else 'good'}>{sv}</td>" if spec_cols else ""
        err = len(g) - len(ok)
        rows.append(f"<tr><td>{html.escape(str(v))}</td><td>{len(g)}</td><td class={'bad' if err else 'good'}>{err}</td>"
                    f"{''.join(cells)}{spec}</tr>")
    spec_head = "<th>spec violations</th>" if spec_cols else ""
    return (f"<table><tr><th>variant</th><th>runs</th><th>errors</th>{head}{spec_head}</tr>"
            + "".join(rows) + "</table>")


def problem_runs(df: pd.DataFrame, event_cols: list[str]) -> str:
    """The runs that failed, had a safety event (any column of ``event_cols`` above 0) or violated a
    spec, with why; a green line only when there is none."""
    spec_cols = [c for c in df.columns if c.startswith("spec.") and c.endswith(".satisfied")]
    whys = {r["run_id"]: (r["error"] if r["status"] != "ok" else "; ".join(_events_of(r, event_cols, spec_cols)))
            for _, r in df.iterrows()}
    bad = df[[(r["status"] != "ok") or bool(whys[r["run_id"]]) for _, r in df.iterrows()]]
    if bad.empty:
        what = ", ".join(event_cols) if event_cols else "no safety event measured"
        return f"<p class=good>No run failed, had a safety event ({html.escape(what)}) or violated a specification.</p>"
    rows = [f"<tr><td>{html.escape(r['run_id'])}</td><td>{html.escape(str(r['status']))}</td>"
            f"<td style='text-align:left'>{html.escape(str(whys[r['run_id']]))}</td></tr>" for _, r in bad.iterrows()]
    return (f"<p class=bad>{len(bad)} of {len(df)} runs failed, had a safety event or violated a specification.</p>"
            "<table><tr><th>run</th><th>status</th><th>why</th></tr>" + "".join(rows) + "</table>")


SENSITIVITY_NOTE = (
    "<p>A field is fitted for a variant only if that variant uses it: a <code>channels.&lt;c&gt;</code> "
    "field if one of the variant's components uses channel &lt;c&gt;; a component's field if the "
    "variant runs that component and its type has that parameter (and the parameter does not "
    "configure another component type); a <code>road</code> field if the variant has a road. Each "
    "variant's scenario is the base with its sweep overrides, validated as its runs are.</p>")


def write_report(df: pd.DataFrame, scenario: Any, path: Path, extra_sections: list[str] | None = None) -> Path:
    """Write ``report.html``: per-variant KPIs, collision probability, distributions, problem runs."""
    ok = df[df["status"] == "ok"]
    variants = list(dict.fromkeys(df["variant"]))
    baseline = variants[0] if variants else ""
    cols = metric_columns(ok) if len(ok) else []
    key = [m for m in scenario.metrics if m in cols] or cols[:6]
    units = units_of(cols, scenario)
    plots = "".join(distribution_plot(ok, c, c, units.get(c, "")) for c in key if len(ok))
    spec_cols = [c for c in cols if c.startswith("spec.") and c.endswith(".space")]
    spec_plots = "".join(distribution_plot(ok, c, f"STL robustness {c}", units.get(c, "")) for c in spec_cols)
    with_coll = collisions_apply(df, scenario)
    skip = not_applicable_draws(ok, scenario) if len(ok) else {}
    events = [c for c in safety_event_columns(df.columns, scenario) if with_coll or c != "collisions"]
    body = [
        f"<h1>{html.escape(scenario.name)}</h1><p>{html.escape(scenario.description)}</p>",
        f"<p>{len(df)} runs ({len(ok)} ok), variants: {', '.join(map(html.escape, variants))}; "
        f"{scenario.duration:g} s simulated per run, warm-up {scenario.warmup:g} s.</p>",
        *(["<h2>Safety: collisions</h2>", collision_table(df)] if with_coll else
          [f"<p>No collision probability: {ENTITY_FREE_REASON} (a macroscopic model), so a count of 0 "
           "collisions would say nothing about safety.</p>"]),
        "<h2>Verdict: safety events, errors and violated specifications per variant</h2>",
        safety_verdict(df, events), problem_runs(df, events),
        "<h2>Key metrics per variant</h2>", kpi_table(ok, key, baseline, units) if len(ok) else "",
        *(["<h2>Paired differences between variants</h2>", paired_table(ok, key)]
          if len(ok) and ok["variant"].nunique() > 1 else []),
        "<h2>Distributions</h2>", plots, spec_plots,
        *(["<h2>Sensitivity to the randomized fields</h2>", SENSITIVITY_NOTE, sensitivity] if (sensitivity := (
            draw_sensitivity(ok, key[0], skip, units.get(key[0], "")) if len(ok) and key else "")) else []),
        *(extra_sections or []),
        "<h2>All metrics</h2>", kpi_table(ok, cols, baseline, units) if len(ok) else "",
        glossary_section([c for c in df.columns if c not in NON_METRICS], scenario),
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"<!doctype html><html><head><meta charset=utf-8><title>{html.escape(scenario.name)}"
                    f"</title><style>{CSS}</style></head><body>{''.join(body)}</body></html>")
    return path


def write_batch_report(df: pd.DataFrame, scenario: Any, out_dir: Path, scenario_path: Path | str | None) -> Path:
    """The ``html`` entry of ``corridor.reports``: ``report.html`` with the sections of every
    ``corridor.report_sections`` entry point (in the order of their names) after the distributions."""
    sections = report_sections(out_dir, df, scenario, scenario_path)
    return write_report(df, scenario, Path(out_dir) / "report.html", extra_sections=sections)
