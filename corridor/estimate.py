"""Rare-event estimates and falsification as batches: ``run_scenario S --estimate EVENT --method M``
and ``--falsify SPEC``.

The statistics are ask/tell objects found through the ``corridor.estimators`` entry-point group
(corridor's own, in ``corridor.analysis.rare``: ``ce``, ``splitting``, ``falsify``); this module runs
what they ask for.  Each stage is a list of runs at standard-normal points ``z`` of the randomized
inputs (``corridor.distributions``), run by the batch executors like any batch (rows written as they
finish, into ``DIR/stages/NNN``), then told back as level values and failure flags.  A stage's points
and run seeds depend only on the seed, the stage number and the rows told before, so ``--resume``
replays the finished stages from their rows and runs only what is missing.  ``naive`` is the plain
batch (``--runs N``) with a Clopper-Pearson interval.  Executor ``inline`` (Python API only) runs a
stage's runs in this process, one after the other: for tests of the estimators on the point-mass
backend, where starting a process would cost 50 times the run.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from corridor.engine import stable_key
from corridor.entrypoints import Registry
from corridor.errors import CorridorError
from corridor.rare_event import Event, Level, check_columns

GROUP = "corridor.estimators"
ESTIMATORS = Registry("method", GROUP)  # rare-event methods: ask/tell classes (corridor.analysis.rare)
MAX_BUDGET = 10_000_000


class EstimateRunError(CorridorError):
    """A run of an estimate failed (an error row): the estimate needs every run (exit 1)."""


@dataclass
class Stage:
    """The runs of one stage, in the order the method asked for them."""

    index: int
    z: np.ndarray
    rows: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class Setup:
    sc: Any
    raw: dict[str, Any]
    path: Path
    out: Path
    variant: str
    seed: int
    event: Event | None
    level: Level
    needed: list[tuple[str, str]] = field(default_factory=list)
    after: dict[str, Any] = field(default_factory=dict)  # --set values, applied after the variant (they win)  # columns to find in the first stage's rows


def method_class(name: str) -> Any:
    """The estimator (or search) class installed as ``name`` in ``corridor.estimators``.

    An unknown name is one line listing the installed methods (``naive``, the plain batch, too).
    """
    if name not in ESTIMATORS:
        raise ESTIMATORS.unknown(name, ["naive", *ESTIMATORS.names()])
    return ESTIMATORS.get(name)


def stage_seeds(seed: int, stage: int, n: int) -> list[int]:
    """The run seeds of a stage (SUMO's, the components' own streams): from the seed and the stage."""
    ss = np.random.SeedSequence(seed, spawn_key=(stable_key("estimate-runs"), stage))
    return [int(s) for s in ss.generate_state(n, dtype=np.uint32)]


def stage_specs(st: Setup, stage: int, z: np.ndarray, tag: str) -> list[Any]:
    from corridor.distributions import draws_from_normal
    from corridor.run import RunSpec

    seeds = stage_seeds(st.seed, stage, len(z))
    specs = []
    for i, (zi, s) in enumerate(zip(z, seeds, strict=True)):
        draws = draws_from_normal(st.sc.randomize, zi)
        specs.append(RunSpec(run_id=f"{st.variant}-{tag}{stage:03d}-{i:05d}", scenario=st.sc.name,
                             source=str(st.path), variant=st.variant, seed=s, base=st.raw,
                             overrides={**st.sc.sweep[st.variant], **draws, **st.after}, draws=draws, out_dir=str(st.out)))
    return specs


def run_stage(st: Setup, stage: int, z: np.ndarray, tag: str, executor: str, workers: int,
              address: str | None, progress: bool) -> Stage:
    """Run (or, resumed, read back) the runs of one stage; an error row stops the estimate."""
    from corridor import batch
    from corridor.results import ResultStore

    specs = stage_specs(st, stage, z, tag)
    store = ResultStore(st.out / "stages" / f"{stage:03d}")
    if executor == "inline":  # in this process, one run after the other (tests: no process start per run)
        from corridor.run import execute

        # every row is written to the store as it finishes (resume as with the other executors); the
        # rows run here are used as they are, only a resumed stage's earlier rows are read back
        done = store.finished()
        fresh = {}
        for spec in specs:
            if spec.run_id not in done:
                row = execute(spec)
                store.write(row)
                fresh[spec.run_id] = {k: (json.dumps(v) if isinstance(v, dict | list) else v) for k, v in row.items()}
        by_id = {r["run_id"]: r for r in store.read().to_dict("records")} if done else {}
        by_id.update(fresh)
    else:
        batch.run_batch(specs, store, executor, workers, address, progress=progress)
        df = store.compact([s.run_id for s in specs])
        by_id = {r["run_id"]: r for r in df.to_dict("records")}
    rows = [by_id.get(s.run_id, {"run_id": s.run_id, "status": "error", "error": "no row"}) for s in specs]
    for spec, r in zip(specs, rows):  # a resumed stage must hold this stage's runs, not another estimate's
        if r.get("status") == "ok" and any(r.get(f"draw.{p}") != v for p, v in spec.draws.items()):
            raise CorridorError(f"{store.dir}: run {r['run_id']} was drawn with other inputs than this estimate "
                                "asks for (a folder of another estimate?); use --overwrite or another --out")
    for r in rows:
        if r.get("status") != "ok":
            raise EstimateRunError(f"run {r['run_id']} failed: {r.get('error')}; an estimate needs every run: "
                                   "fix the cause and continue with --resume")
        r["estimate.stage"] = stage
    return Stage(stage, z, rows)


def drive(st: Setup, method: Any, tag: str, executor: str, workers: int, address: str | None,
          progress: bool, stop: Any = None) -> list[Stage]:
    """Ask, run, tell until the method is done (or ``stop(stage)`` says so)."""
    stages: list[Stage] = []
    while (z := method.ask()) is not None:
        stage = run_stage(st, len(stages), np.atleast_2d(z), tag, executor, workers, address, progress)
        stages.append(stage)
        if len(stages) == 1:  # EVENT and --level columns, judged on the first rows before anything is told
            check_columns(st.needed, row_columns(stage.rows), True)
        level = np.array([st.level.of(r) for r in stage.rows])
        fail = np.array([st.event.fails(r) if st.event else bool(lv < 0) for r, lv in zip(stage.rows, level)])
        method.tell(level, fail)
        for r, lv, f in zip(stage.rows, level, fail):
            r["estimate.level"], r["estimate.fail"] = float(lv), bool(f)
        if stop is not None and stop(stage):
            break
    return stages


def column_watch(st: Setup, first: int = 50) -> Any:
    """A batch ``on_row`` callback for the plain batch of ``naive``: EVENT's and ``--level``'s columns
    are judged on the first ``first`` ok rows (a stage's worth), not after the whole budget."""
    seen: set[str] = set()
    count = [0]

    def on_row(row: dict[str, Any]) -> None:
        if row.get("status") != "ok" or count[0] >= first:
            return
        seen.update(row)
        count[0] += 1
        if count[0] == first:
            check_columns(st.needed, seen, True)

    return on_row


def row_columns(rows: list[dict[str, Any]]) -> set[str]:
    """The columns of the ok rows (every column a run of the scenario wrote)."""
    return {k for r in rows if r.get("status") == "ok" for k in r}


def rerun_command(st: Setup, row: dict[str, Any], sets: list[str]) -> str:
    """A plain ``run_scenario`` command that runs exactly this run (every draw fixed with --set)."""
    parts = ["run_scenario", str(st.path), "--variant", st.variant, "--seed", str(row["seed"])]
    for s in sets:
        parts += ["--set", s]
    for path in sorted(st.sc.randomize):
        parts += ["--set", f"{path}={json.dumps(row[f'draw.{path}'])}"]
    return " ".join(_quote(p) for p in parts)


def _quote(text: str) -> str:
    import shlex

    return shlex.quote(text)


def likely_failures(st: Setup, rows: list[dict[str, Any]], sets: list[str], k: int = 5) -> list[dict[str, Any]]:
    """The failing runs whose inputs are most likely under the nominal distributions (the sum of the
    fields' log densities), with the command that re-runs each."""
    from corridor.distributions import logpdf

    out = []
    for r in rows:
        if r.get("estimate.fail"):
            lp = sum(logpdf(d, r[f"draw.{p}"]) for p, d in st.sc.randomize.items())
            out.append({"run_id": r["run_id"], "seed": int(r["seed"]), "nominal_logpdf": float(lp),
                        "level": r.get("estimate.level"),
                        "draws": {p: _plain(r[f"draw.{p}"]) for p in sorted(st.sc.randomize)},
                        "rerun": rerun_command(st, r, sets)})
    out.sort(key=lambda e: -e["nominal_logpdf"])
    return out[:k]


def _plain(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


def write_rows(out: Path, stages: list[Stage]) -> Any:
    """All stages' rows in ``DIR/runs.parquet`` (stage order), for the report and the user."""
    import pandas as pd

    rows = [r for s in stages for r in s.rows]
    df = pd.DataFrame(rows)
    tmp = out / ".runs.parquet.tmp"
    df.to_parquet(tmp, index=False)
    tmp.replace(out / "runs.parquet")
    return df


def write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1, default=_plain, allow_nan=True))
    tmp.replace(path)


def runs_for_same_precision(p: float, rel_half_width: float) -> float:
    """Plain Monte Carlo runs for the same relative 95 % half-width: ``z^2 (1 - p) / (p r^2)``."""
    if not (p > 0 and rel_half_width > 0 and math.isfinite(rel_half_width)):
        return math.nan
    return 1.959963984540054**2 * (1 - p) / (p * rel_half_width**2)


def _finite(*values: Any) -> bool:
    return all(isinstance(v, int | float) and math.isfinite(v) for v in values)


def estimate_lines(data: dict[str, Any]) -> list[str]:
    """The estimate and its comparison with plain Monte Carlo, in words where a number is unknown
    (no failing run: no interval; an interval of one run: no precision) - never a printed NaN."""
    res, n = data["result"], data["result"]["runs"]
    p, (lo, hi) = res["estimate"], res["ci95"]
    head = f"P({data['event']})"
    if not _finite(p):
        return [f"{head}: not estimated ({res['method']}, {n} runs)"]
    if _finite(lo, hi):
        lines = [f"{head} ~= {p:.4g}  95 % CI [{lo:.4g}, {hi:.4g}]  ({res['method']}, {n} runs)"]
    elif p == 0:
        lines = [f"{head}: no failing run among {n} ({res['method']}): no estimate above 0 and no upper "
                 "bound from these runs; a larger --budget (or a --level that leads closer to the event) may reach it"]
    else:
        lines = [f"{head} ~= {p:.4g}  ({res['method']}, {n} runs; too few failures for an interval)"]
    mc = res["plain_mc_same_runs"]["ci95"]
    if p > 0 and _finite(*mc):
        need, ratio = res["plain_runs_same_precision"], res["runs_ratio"]
        same = (f"; the same precision needs ~{need:.3g} plain runs ({ratio:.3g} x)" if _finite(need, ratio)
                else "")
        lines.append(f"plain Monte Carlo with {n} runs and ~{p * n:.3g} failures: 95 % CI [{mc[0]:.3g}, {mc[1]:.3g}]{same}")
    return lines


def print_rare(data: dict[str, Any]) -> None:
    """The terminal summary of an estimate or a falsification."""
    res = data["result"]
    if data["kind"] == "falsify":
        if data["counterexample"]:
            print(f"violation of spec '{data['falsify']}' found: run {data['best_run']}, robustness "
                  f"{data['best_robustness']:.4g} ({res['runs']} runs)\ncounterexample: {data['counterexample']}  "
                  f"(re-run: run_scenario {data['counterexample']})")
        else:
            print(f"no violation of spec '{data['falsify']}' found in {res['runs']} runs; lowest robustness "
                  f"{data['best_robustness']:.4g} (run {data['best_run']})")
        return
    for line in estimate_lines(data):
        print(line)
    if res.get("missed_mode_warning"):
        print(f"warning: {res['missed_mode_warning']}")
    for f in data["likely_failures"][:3]:
        print(f"failure {f['run_id']} (nominal log density {f['nominal_logpdf']:.3g}): {f['rerun']}")
