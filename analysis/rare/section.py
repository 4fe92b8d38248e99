"""The report section of a rare-event estimate or falsification (``corridor.report_sections``
entry ``estimate``): reads ``DIR/estimate.json`` or ``DIR/falsify.json`` when the batch wrote one."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any


def _n(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}" if isinstance(x, float) else html.escape(str(x))


def _table(head: list[str], rows: list[list[Any]]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{_n(c) if not isinstance(c, str) else html.escape(c)}</td>" for c in r)
                   + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _failures(items: list[dict[str, Any]]) -> str:
    if not items:
        return "<p>No failing run.</p>"
    rows = [[f["run_id"], f["nominal_logpdf"], f["level"], f"<code>{html.escape(f['rerun'])}</code>"] for f in items]
    out = _table(["run", "nominal log density", "level", "re-run"], [r[:3] + [""] for r in rows])
    for r in rows:  # the command cell holds markup: put it in after escaping the rest
        out = out.replace("<td></td>", f"<td>{r[3]}</td>", 1)
    return "<h3>Most likely failures (highest nominal density of the inputs)</h3>" + out


def _ci(res: dict[str, Any]) -> str:
    """The interval, or in words why there is none (never a NaN bound)."""
    lo, hi = res["ci95"]
    if all(isinstance(v, int | float) and math.isfinite(v) for v in (lo, hi)):
        return f"[{_n(lo)}, {_n(hi)}]"
    return "none: no failing run" if res.get("estimate") == 0 else "none: too few failures"


def estimate_section(data: dict[str, Any]) -> str:
    from corridor.estimate import estimate_lines

    res = data["result"]
    mc = res.get("plain_mc_same_runs", {})
    parts = [f"<h2>Rare-event estimate: P({html.escape(data['event'])})</h2>",
             "<p>The runs of this batch were drawn from the method's proposals, not from the nominal "
             "distributions: the plain tables above describe them, not the scenario; the estimate below "
             "weights them back.</p>",
             _table(["method", "runs", "estimate", "95 % CI", "plain MC, same runs (CI)", "plain runs for same precision",
                     "ratio"],
                    [[res["method"], res["runs"], res["estimate"], _ci(res),
                      f"[{_n(mc.get('ci95', [None])[0])}, {_n(mc.get('ci95', [None, None])[1])}]",
                      res.get("plain_runs_same_precision"), res.get("runs_ratio")]])]
    parts.append("<p>" + "<br>".join(html.escape(line) for line in estimate_lines(data)) + "</p>")
    if res.get("missed_mode_warning"):
        parts.append(f"<p><strong>Warning:</strong> {html.escape(res['missed_mode_warning'])}</p>")
    keys = [k for k in ("ess", "ess_failures", "weight_max", "weight_cv", "max_weight_share_failures", "cv",
                        "p0", "runs_per_level", "converged", "reached_failure", "components",
                        "uncovered_failures") if k in res]
    if keys:
        parts.append(_table(keys, [[res[k] if not isinstance(res[k], bool) else str(res[k]) for k in keys]]))
    path = res.get("path") or []
    if path:
        head = sorted({k for p in path for k in p}, key=lambda k: list(path[0]).index(k) if k in path[0] else 99)
        parts.append("<h3>Stages (level / proposal path)</h3>" + _table(head, [[str(p.get(k, "")) if isinstance(p.get(k), list | bool) else p.get(k, "") for k in head] for p in path]))
    modes = res.get("modes") or []
    if modes:
        parts.append("<h3>Proposal components (failure modes) and their share of the estimate</h3>"
                     + _table(["component", "sampling share", "failures", "estimate", "mean (z)", "std (z)"],
                              [[m["component"], m["share"], m["failures"], m["estimate"], str(m["mean"]),
                                str(m["std"])] for m in modes]))
    parts.append(_failures(data.get("likely_failures", [])))
    return "<section>" + "".join(parts) + "</section>"


def falsify_section(data: dict[str, Any]) -> str:
    res = data["result"]
    verdict = (f"violation found: run {html.escape(data['best_run'])}, robustness {_n(data['best_robustness'])}; "
               f"<code>run_scenario {html.escape(str(data['counterexample']))}</code> reproduces it"
               if data["counterexample"] else
               f"no violation in {res['runs']} runs; lowest robustness {_n(data['best_robustness'])}")
    rows = [[p["stage"], p["runs"], p["min_level"], p["best_level"], p["sigma"]] for p in res["path"]]
    draws = _table(["input", "value"], [[k, v] for k, v in data["best_draws"].items()])
    return (f"<section><h2>Falsification of spec '{html.escape(data['falsify'])}' ({html.escape(res['method'])})</h2>"
            f"<p>{verdict}</p><h3>Lowest-robustness inputs (seed {data['best_seed']})</h3>{draws}"
            f"<h3>Generations</h3>{_table(['stage', 'runs', 'min robustness', 'best so far', 'step (sigma)'], rows)}</section>")


def report_sections(out_dir: Path, df: Any, scenario: Any, scenario_path: Path | str | None) -> list[str]:
    out = []
    for name, fn in (("estimate.json", estimate_section), ("falsify.json", falsify_section)):
        path = Path(out_dir) / name
        if path.exists():
            out.append(fn(json.loads(path.read_text())))
    return out
