"""``estimate`` and ``falsify``: the Python entry points behind ``run_scenario --estimate/--falsify``.

Inputs are checked (one-line ``CorridorError``) and the batch folder opened and locked before any
run; the folder's manifest includes the estimate's settings, so ``--resume`` continues only the same
estimate.  Results: ``DIR/estimate.json`` (or ``DIR/falsify.json`` and ``DIR/counterexample.yaml``),
``DIR/runs.parquet`` (every stage's rows) and ``DIR/report.html``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from corridor.batchdir import manifest_for, open_batch_dir
from corridor.errors import CorridorError, clip
from corridor.estimate import (
    MAX_BUDGET,
    EstimateRunError,
    Setup,
    column_watch,
    drive,
    likely_failures,
    method_class,
    runs_for_same_precision,
    write_json,
    write_rows,
)
from corridor.rare_event import (
    ColumnError,
    check_columns,
    known_columns,
    needed_columns,
    parse_event,
    parse_level,
)
from corridor.scenario import set_overrides


def _setup(scenario: str | Path, sets: Sequence[str], variant: str | None, seed: int | None, budget: int,
           out: str | Path | None, suffix: str) -> tuple[Any, dict[str, Any], Path, str, int, Path]:
    from corridor.api import _int, check_options
    from corridor.scenario import MAX_SEED, load, resolve_scenario

    if not 1 <= _int("budget", budget) <= MAX_BUDGET:
        raise CorridorError(f"--budget must be 1..{MAX_BUDGET} runs, got {budget}")
    check_options(seed=seed, sets=sets)
    if variant is not None and not isinstance(variant, str):
        raise CorridorError(f"variant must be a string (one sweep variant), got {variant!r:.40}")
    path = resolve_scenario(str(scenario))
    sc, raw = load(path, list(sets))
    if variant is not None and variant not in sc.sweep:
        raise CorridorError(f"{path}: --variant {clip(variant)}: not in sweep ({', '.join(sc.sweep)})")
    first = sc.seed if seed is None else seed
    if not 0 <= first <= MAX_SEED:
        raise CorridorError(f"--seed must lie in 0..{MAX_SEED}")
    out_dir = Path(out) if out is not None else Path("results") / f"{sc.name}-{suffix}"
    return sc, raw, path, variant or next(iter(sc.sweep)), first, out_dir


def _open(sc: Any, raw: dict[str, Any], path: Path, out: Path, sets: Sequence[str], settings: dict[str, Any],
          resume: bool, overwrite: bool) -> Any:
    return open_batch_dir(out, manifest_for(sc.name, str(path), {**raw, "_estimate": settings}, list(sets)),
                          resume, overwrite)


def estimate(scenario: str | Path, event: str, *, method: str = "ce", budget: int = 1000, level: str | None = None,
             seed: int | None = None, sets: Sequence[str] = (), variant: str | None = None,
             out: str | Path | None = None, resume: bool = False, overwrite: bool = False,
             executor: str = "local", workers: int = 2, address: str | None = None, progress: bool = False,
             report: bool = True) -> dict[str, Any]:
    """Estimate P(EVENT) over the scenario's randomized inputs; returns ``estimate.json``'s content."""
    from corridor.api import _int, check_options

    _int("budget", budget)
    parse_event(event)  # its form first (the spec name is checked once the scenario is loaded)
    check_options(executor=executor if executor != "inline" else "local", workers=workers)
    if not isinstance(method, str):
        raise CorridorError(f"method must be a string, got {method!r:.40}")
    sc, raw, path, var, first, out_dir = _setup(scenario, sets, variant, seed, budget, out, method)
    ev = parse_event(event, [s.name for s in sc.specs])
    lvl = parse_level(level) if level else ev.default_level()
    needed = needed_columns(ev, lvl if level else None) if method == "naive" else needed_columns(ev, lvl)
    check_columns(needed, known_columns(sc), from_rows=False)
    if method != "naive":
        method_class(method)
        if not sc.randomize:
            raise CorridorError(f"{path}: --method {method} samples the randomize entries, and the scenario has none")
        if lvl is None:
            raise CorridorError(f"--estimate {clip(event)}: give --level COLUMN (smaller is closer to failure) "
                                "for the adaptive methods")
        cls = _estimator(method, budget)
    settings = {"event": ev.text, "method": method, "budget": budget, "level": str(lvl) if lvl else None,
                "seed": first, "variant": var}
    # naive is the plain batch: like --runs, a larger --budget extends it on --resume
    fixed = {k: v for k, v in settings.items() if not (method == "naive" and k == "budget")}
    bdir = _open(sc, raw, path, out_dir, sets, fixed, resume, overwrite)
    try:
        st = Setup(sc, raw, path, out_dir, var, first, ev, lvl or parse_level("collisions"), needed,
                   set_overrides(sets))
        if method == "naive":
            res, rows = _naive(st, budget, executor, workers, address, progress)
        else:
            m = cls(len(sc.randomize), budget, first)
            stages = drive(st, m, method, executor, workers, address, progress)
            rows = [r for s in stages for r in s.rows]
            res = {**m.result(), "runs": len(rows), "stages": len(stages)}
        res = _compare(res)
        data = {"kind": "estimate", "scenario": sc.name, "source": str(path), **settings, "sets": list(sets),
                "inputs": sorted(sc.randomize), "result": res, "likely_failures": likely_failures(st, rows, list(sets))}
        write_json(out_dir / "estimate.json", data)
        if report or method != "naive":
            import pandas as pd

            df = write_rows(out_dir, stages) if method != "naive" else pd.read_parquet(out_dir / "runs.parquet")
            if report:
                from corridor.reports import write_reports

                write_reports(df, sc, out_dir, path)
        return data
    except ColumnError:  # refused input, only a row could show it: as if the folder was never touched
        bdir.discard()
        raise
    finally:
        bdir.close()


def _estimator(method: str, budget: int) -> Any:
    """The estimator class of ``--method``.

    A search (``falsify``) or a budget below the method's ``MIN_BUDGET`` is refused in one line
    naming the minimum.
    """
    cls = method_class(method)
    if getattr(cls, "KIND", "estimator") != "estimator":
        raise CorridorError(f"--method {clip(method)}: a search, not an estimator of P(EVENT); use --falsify SPEC for it")
    least = int(getattr(cls, "MIN_BUDGET", 1))
    if budget < least:
        raise CorridorError(f"--method {method} --budget {budget}: the method needs at least {least} runs "
                            f"({getattr(cls, 'MIN_BUDGET_WHY', 'its first stages')}); give --budget {least} "
                            "or more, or --method naive")
    return cls


def _naive(st: Setup, budget: int, executor: str, workers: int, address: str | None,
           progress: bool) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Plain Monte Carlo: the batch ``--runs budget`` itself, with its Clopper-Pearson interval."""
    from corridor import batch
    from corridor.results import ResultStore
    from corridor.stats import clopper_pearson

    plan = batch.expand(st.sc, st.raw, str(st.path), budget, st.seed, str(st.out), [st.variant], st.after)
    store = ResultStore(st.out)
    batch.run_batch(plan, store, executor, workers, address, progress=progress,
                    on_row=column_watch(st) if st.needed else None)
    df = store.compact(plan.rank)
    ok = df[df["status"] == "ok"]
    rows = ok.to_dict("records")
    if len(ok):
        check_columns(st.needed, set(ok.columns), True)
    if len(ok) < len(df):
        bad = df[df["status"] != "ok"].iloc[0]
        raise EstimateRunError(f"{len(df) - len(ok)} of {len(df)} runs failed (run {bad['run_id']}: {bad['error']}); "
                               "an estimate needs every run: fix the cause and continue with --resume")
    assert st.event is not None  # the parsed --estimate EVENT (only a stage-driven search has none)
    for r in rows:
        r["estimate.level"], r["estimate.fail"] = st.level.of(r), st.event.fails(r)
    k, n = sum(r["estimate.fail"] for r in rows), len(rows)
    lo, hi = clopper_pearson(k, n)
    p = k / n if n else math.nan
    return {"method": "naive", "estimate": p, "ci95": [lo, hi], "failures": int(k), "runs": n,
            "errors": int(len(df) - n), "rel_half_width": (hi - lo) / 2 / p if p else math.nan}, rows


def _compare(res: dict[str, Any]) -> dict[str, Any]:
    """Add what plain Monte Carlo would give beside the estimate.

    That is the plain interval of as many runs with as many failures as the estimate implies, and
    the plain runs needed for the estimate's precision.
    """
    from corridor.stats import clopper_pearson

    n, p = res.get("runs", 0), res.get("estimate", math.nan)
    k = int(round(p * n)) if p == p else 0
    lo, hi = clopper_pearson(k, n)
    need = runs_for_same_precision(p, res.get("rel_half_width", math.nan))
    return {**res, "plain_mc_same_runs": {"runs": n, "expected_failures": p * n, "ci95": [lo, hi]},
            "plain_runs_same_precision": need, "runs_ratio": need / n if n and need == need else math.nan}


def falsify(scenario: str | Path, spec: str, *, budget: int = 200, seed: int | None = None,
            sets: Sequence[str] = (), variant: str | None = None, out: str | Path | None = None,
            resume: bool = False, overwrite: bool = False, executor: str = "local", workers: int = 2,
            address: str | None = None, progress: bool = False, report: bool = True) -> dict[str, Any]:
    """Minimise spec ``spec``'s robustness over the randomized inputs (CMA-ES).

    On a violation it writes ``DIR/counterexample.yaml`` (the scenario with the violating inputs and
    seed fixed).
    """
    from corridor.api import check_options

    check_options(executor=executor if executor != "inline" else "local", workers=workers)
    sc, raw, path, var, first, out_dir = _setup(scenario, sets, variant, seed, budget, out, "falsify")
    names = [s.name for s in sc.specs]
    if not isinstance(spec, str) or spec.strip() not in names:
        raise CorridorError(f"--falsify {clip(str(spec))}: no spec of that name in the scenario "
                            f"(specs: {', '.join(names) or 'none declared'})")
    ev = parse_event(f"spec:{spec}", names)
    if not sc.randomize:
        raise CorridorError(f"{path}: --falsify searches the randomize entries, and the scenario has none")
    settings = {"falsify": spec, "budget": budget, "seed": first, "variant": var}
    bdir = _open(sc, raw, path, out_dir, sets, settings, resume, overwrite)
    try:
        level = ev.default_level()
        assert level is not None  # a spec's event: its robustness is the level
        st = Setup(sc, raw, path, out_dir, var, first, ev, level, after=set_overrides(sets))
        m = method_class("falsify")(len(sc.randomize), budget, first)
        stages = drive(st, m, "f", executor, workers, address, progress)
        rows = [r for s in stages for r in s.rows]
        best = min(rows, key=lambda r: r["estimate.level"] if r["estimate.level"] == r["estimate.level"] else math.inf)
        data = {"kind": "falsify", "scenario": sc.name, "source": str(path), **settings, "sets": list(sets),
                "inputs": sorted(sc.randomize), "result": m.result(), "best_run": best["run_id"],
                "best_seed": int(best["seed"]), "best_robustness": best["estimate.level"],
                "best_draws": {p: best[f"draw.{p}"] for p in sorted(sc.randomize)}, "counterexample": None}
        if best["estimate.fail"]:
            cex = out_dir / "counterexample.yaml"
            write_counterexample(cex, path, list(sets), var, best, sorted(sc.randomize), spec)
            data["counterexample"] = str(cex)
        write_json(out_dir / "falsify.json", data)
        df = write_rows(out_dir, stages)
        if report:
            from corridor.reports import write_reports

            write_reports(df, sc, out_dir, path)
        return data
    finally:
        bdir.close()


def write_counterexample(dest: Path, path: Path, sets: list[str], variant: str, row: dict[str, Any],
                         inputs: list[str], spec: str) -> None:
    """Write the scenario with the run's seed and every draw fixed in its variant's overrides.

    ``extends`` and ``--set`` are resolved, so ``run_scenario counterexample.yaml`` runs exactly that
    run again.
    """
    import yaml

    from corridor.estimate import _plain
    from corridor.scenario import load_raw

    data = load_raw(path, sets)
    draws = {p: _plain(row[f"draw.{p}"]) for p in inputs}
    data["name"] = f"{data['name']}-cex"[:64]
    data["seed"] = int(row["seed"])
    data["sweep"] = {variant: {**(data.get("sweep") or {}).get(variant, {}), **draws}}
    data.pop("randomize", None)
    head = (f"# Counterexample of spec '{spec}' found by run_scenario {path} --falsify {spec}: run {row['run_id']}\n"
            f"# robustness {row['estimate.level']:.6g} < 0.  Re-run it with: run_scenario {dest}\n")
    tmp = dest.with_name(f".{dest.name}.tmp")
    tmp.write_text(head + yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    tmp.replace(dest)
