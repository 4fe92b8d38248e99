"""``run_scenario SCENARIO --learn KEYS --objective EXPR --budget N --method blrl|cma|ppo``: learn boundaries.

The boundary parameters ``KEYS`` (``avoid_enter.dist_m`` or the full path
``controllers.avoid.params.boundaries.avoid_enter.dist_m``) of one sweep variant are tuned to
maximise ``EXPR`` over the run's row minus ``PENALTY`` x the number of broken ``--constraint``s,
over the scenario's ``randomize`` distribution.  Positive parameters are searched in log space.

- ``blrl`` (boundary-localised policy gradient, after Grudic & Ungar): a stage is ``RUNS_PER_STAGE``
  runs at the current theta with stochastic switching near the boundaries (``SwitchingParams``:
  each decision as if theta were scaled by e^eps, eps logistic with scale T in log units, T starting
  at CMA-ES's first step and annealed by ``ANNEAL`` per stage); each row carries the summed score
  d log pi / d theta of its draws, and the step is REINFORCE with a leave-one-out baseline,
  normalised to ``STEP`` in log space (shrinking per stage).  A stage whose runs drew no switch
  near the boundary has no gradient: theta stays (the method only learns where decisions are close).
- ``cma``: CMA-ES (the ``cma`` package) on the same log parameters, one run per candidate,
  deterministic switching.
- ``ppo``: stable-baselines3 PPO through the Gymnasium environment (``corridor.learn_ppo``): it learns a
  policy, not theta (no ``learned.yaml``; ``ppo_policy.zip`` instead).

Stages run through the batch executors and write their rows as they finish (``--resume`` continues).
At the end theta0 and the learned theta are both run on ``--holdout`` seeds never used in training
(common random numbers: the same draws for both), deterministic switching; the paired difference of
the objective gets a 95 % t interval.  Results: ``DIR/learn.json``, ``DIR/learned.yaml`` (the scenario
with the learned theta, which ``run_scenario`` re-runs) and ``DIR/runs.parquet``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from corridor.errors import CorridorError, clip
from corridor.learn_core import PENALTIES, PPO_EPISODES_PER_STAGE, Problem
from corridor.learn_core import ci95 as _ci
from corridor.learn_core import finite as _f
from corridor.learn_core import is_nan as _nan
from corridor.learn_core import specs as _specs
from corridor.learn_core import summary as _summary
from corridor.objective import Expression, value

RUNS_PER_STAGE = 8  # blrl
CMA_POPSIZE = 6
MIN_STAGES = 2
CMA_SIGMA0 = 0.5  # CMA-ES's first step [log units]
T0 = CMA_SIGMA0  # blrl's initial temperature [log units of theta]: the same exploration width as CMA-ES
ANNEAL = 0.8  # T per stage
STEP = 0.4  # first blrl step [log units], then STEP / sqrt(1 + stage)
METHODS = ("blrl", "cma", "ppo")


def min_budget(method: str) -> int:
    """Runs the method needs for ``MIN_STAGES`` stages."""
    per_stage = {"blrl": RUNS_PER_STAGE, "cma": CMA_POPSIZE, "ppo": PPO_EPISODES_PER_STAGE}
    return MIN_STAGES * per_stage.get(method, RUNS_PER_STAGE)


def boundary_params(sc: Any, raw: dict[str, Any], variant: str) -> dict[str, dict[str, float]]:
    """controller name -> {``boundary.param``: value} of the variant's controllers that have boundaries
    (and stochastic switching)."""
    from corridor.scenario import apply_overrides, validate
    from corridor.variants import component_class

    vsc = validate(apply_overrides(raw, dict(sc.sweep[variant])), f"{sc.name} [{variant}]")
    out: dict[str, dict[str, float]] = {}
    for name, spec in vsc.controllers.items():
        cls = component_class("controllers", spec)
        model = getattr(cls, "Params", None)
        if model is None or "boundaries" not in model.model_fields or "switching" not in model.model_fields:
            continue
        bd = model.model_validate(spec.params).boundaries.model_dump()
        out[name] = {f"{b}.{k}": float(v) for b, ps in bd.items() for k, v in ps.items()}
    return out


def declared_columns(sc: Any, raw: dict[str, Any], variant: str) -> set[str]:
    """The columns the variant's components declare (``Metric`` names without wildcards)."""
    from corridor.run import DEFAULT_MONITORS
    from corridor.scenario import apply_overrides, validate
    from corridor.variants import component_class

    vsc = validate(apply_overrides(raw, dict(sc.sweep[variant])), f"{sc.name} [{variant}]")
    out: set[str] = set()
    for table, specs in (("backends", vsc.backends), ("controllers", vsc.controllers),
                         ("monitors", {**DEFAULT_MONITORS, **vsc.monitors})):
        for spec in specs.values():
            cls = component_class(table, spec)
            out |= {m.name for m in (getattr(cls, "metrics", None) or ()) if "*" not in m.name}
    return out


def resolve_keys(sc: Any, raw: dict[str, Any], variant: str, keys: str) -> tuple[str, list[str], np.ndarray]:
    """(controller, full key paths, their current values) of ``--learn KEYS`` (comma-separated)."""
    have = boundary_params(sc, raw, variant)
    if not have:
        raise CorridorError(f"--learn: variant {variant!r} of {sc.name} has no controller with boundaries")
    found: list[tuple[str, str, float]] = []
    for key in [k.strip() for k in keys.split(",") if k.strip()]:
        short = key.split(".params.boundaries.", 1)[-1]
        ctrl = key.split(".")[1] if key.startswith("controllers.") else None
        hits = [(c, short, ps[short]) for c, ps in have.items() if short in ps and ctrl in (None, c)]
        if len(hits) != 1:
            import difflib

            names = sorted({k for ps in have.values() for k in ps})
            near = difflib.get_close_matches(short, names, n=3)
            hint = f"did you mean {', '.join(near)}?" if near else f"have {', '.join(names)}"
            raise CorridorError(f"--learn {clip(key)}: no such boundary parameter ({hint})")
        found.append(hits[0])
    if not found:
        raise CorridorError("--learn: give at least one boundary parameter (e.g. avoid_enter.dist_m)")
    ctrls = {c for c, _, _ in found}
    if len(ctrls) > 1:
        raise CorridorError(f"--learn: the keys name several controllers ({', '.join(sorted(ctrls))}); learn one")
    ctrl = ctrls.pop()
    return ctrl, [f"controllers.{ctrl}.params.boundaries.{k}" for _, k, _ in found], np.array([v for *_, v in found])


def problem(scenario: str | Path, keys: str, objective: str, constraints: Sequence[str], budget: int, method: str,
            variant: str | None, sets: Sequence[str], penalty: str = "count") -> Problem:
    """Check every input (one-line ``CorridorError``) and build the problem."""
    from corridor.rare_event import known_columns
    from corridor.scenario import load, resolve_scenario, set_overrides

    if method not in METHODS:
        raise CorridorError(f"--method {clip(str(method))}: --learn methods are {', '.join(METHODS)}")
    if penalty not in PENALTIES:
        raise CorridorError(f"--penalty {clip(str(penalty))}: one of {', '.join(PENALTIES)}")
    if not isinstance(budget, int) or budget < min_budget(method):
        raise CorridorError(f"--budget {budget}: {method} needs at least {min_budget(method)} runs "
                            f"({MIN_STAGES} stages)")
    obj = Expression(objective, "--objective")
    cons = [Expression(c, "--constraint") for c in constraints]
    path = resolve_scenario(str(scenario))
    sc, raw = load(path, list(sets))
    var = variant or next(iter(sc.sweep))
    if var not in sc.sweep:
        raise CorridorError(f"{path}: --variant {clip(var)}: not in sweep ({', '.join(sc.sweep)})")
    if not sc.randomize:
        raise CorridorError(f"{path}: --learn samples the randomize entries, and the scenario has none")
    cols = known_columns(sc) | {"events_mode", "events_fallback"} | declared_columns(sc, raw, var)
    obj.check_columns(cols, "--objective")
    for c in cons:
        c.check_columns(cols, "--constraint")
    ctrl, full, theta0 = resolve_keys(sc, raw, var, keys)
    pairs, bounds = hysteresis_pairs(sc, raw, var, ctrl, full, theta0)
    return Problem(sc, raw, path, var, ctrl, full, theta0, theta0 > 0, obj, cons, set_overrides(sets),
                   pairs=pairs, bounds=bounds, penalty=penalty)


def hysteresis_pairs(sc: Any, raw: dict[str, Any], variant: str, ctrl: str, keys: list[str], theta0: np.ndarray,
                     ) -> tuple[list[tuple[int, int, int]], list[tuple[int, float, int]]]:
    """The learned keys' hysteresis pairs (``Problem.pairs``) and clamps (``Problem.bounds``), from the
    controller's ``boundaries`` model ``hysteresis``; a start that inverts one is refused."""
    from corridor.scenario import apply_overrides, validate
    from corridor.variants import component_class

    vsc = validate(apply_overrides(raw, dict(sc.sweep[variant])), f"{sc.name} [{variant}]")
    model = component_class("controllers", vsc.controllers[ctrl]).Params.model_fields["boundaries"].annotation
    hyst: dict[str, tuple[str, int]] = dict(getattr(model, "hysteresis", {}) or {})
    now = boundary_params(sc, raw, variant)[ctrl]
    short = [k.split(".params.boundaries.", 1)[1] for k in keys]
    pairs: list[tuple[int, int, int]] = []
    bounds: list[tuple[int, float, int]] = []
    for follower, (anchor, d) in hyst.items():
        for param in {k.split(".", 1)[1] for k in now if k.startswith(f"{follower}.")}:
            f, a = f"{follower}.{param}", f"{anchor}.{param}"
            if a not in now:
                continue
            if d * (now[f] - now[a]) < 0:
                raise CorridorError(f"--learn: {f} = {now[f]:g} and {a} = {now[a]:g} invert the hysteresis "
                                    f"({f} must be {'>=' if d > 0 else '<='} {a}); fix the start")
            if f in short and a in short:
                pairs.append((short.index(f), short.index(a), d))
            elif f in short:
                bounds.append((short.index(f), now[a], d))
            elif a in short:
                bounds.append((short.index(a), now[f], -d))
    for i, j, _d in pairs:
        if not (theta0[i] > 0 and theta0[j] > 0):
            raise CorridorError(f"--learn: {short[i]} and {short[j]} must be positive to be learned as a pair")
    return pairs, bounds


# ---- stages ------------------------------------------------------------------------------------------
def _run(specs: list[Any], store_dir: Path, executor: str, workers: int, address: str | None,
         progress: bool) -> list[dict[str, Any]]:
    from corridor import batch
    from corridor.results import ResultStore

    store = ResultStore(store_dir)
    batch.run_batch(specs, store, executor, workers, address, progress=progress)
    df = store.compact([s.run_id for s in specs])
    by_id = {r["run_id"]: r for r in df.to_dict("records")}
    return [by_id.get(s.run_id, {"run_id": s.run_id, "status": "error", "error": "no row"}) for s in specs]


def _score(pb: Problem, row: dict[str, Any]) -> np.ndarray:
    """d log pi / d theta of one run (summed over its draws), per key."""
    cols = [f"blrl.score.{pb.controller}.{k.split('.params.boundaries.', 1)[1]}" for k in pb.keys]
    return np.array([float(row.get(c) or 0.0) if not _nan(row.get(c)) else 0.0 for c in cols])


def blrl(pb: Problem, budget: int, seed: int, out: Path, run: Any) -> tuple[np.ndarray, list[dict[str, Any]]]:
    u, curve = pb.u0(), []
    for stage in range(budget // RUNS_PER_STAGE):
        temp = T0 * ANNEAL**stage
        theta = pb.theta(u)
        rows = run(_specs(pb, out, seed, "train", stage, np.tile(theta, (RUNS_PER_STAGE, 1)), temp), stage)
        r = np.array([pb.reward(x) for x in rows])
        s = np.array([_score(pb, x) for x in rows])  # (K, d) d log pi / d theta
        ok = np.isfinite(r)
        k = int(ok.sum())
        grad_u = np.zeros_like(u)
        if k >= 2:
            base = (r[ok].sum() - r[ok]) / (k - 1)  # leave-one-out baseline
            grad_theta = ((r[ok] - base)[:, None] * s[ok]).mean(axis=0)
            grad_u = pb.grad_u(grad_theta, theta)
        norm = float(np.linalg.norm(grad_u))
        if norm > 0:
            u = u + STEP / math.sqrt(1 + stage) * grad_u / norm
        curve.append({"stage": stage, "theta": theta.tolist(), "temperature": temp, "grad_norm": norm,
                      "draws": float(np.nansum([float(x.get("blrl.draws") or 0) for x in rows])),
                      **_summary(r, rows, pb)})
    return pb.theta(u), curve


def cma_es(pb: Problem, budget: int, seed: int, out: Path, run: Any) -> tuple[np.ndarray, list[dict[str, Any]]]:
    import cma

    es = cma.CMAEvolutionStrategy(pb.u0().tolist(), CMA_SIGMA0, {"popsize": CMA_POPSIZE, "seed": seed + 1, "verbose": -9})
    curve = []
    for stage in range(budget // CMA_POPSIZE):
        us = np.array(es.ask())
        thetas = np.array([pb.theta(x) for x in us])
        rows = run(_specs(pb, out, seed, "train", stage, thetas, None), stage)
        r = np.array([pb.reward(x) for x in rows])
        es.tell(list(us), [(-x if math.isfinite(x) else 1e9) for x in r])
        curve.append({"stage": stage, "theta": pb.theta(np.asarray(es.result.xfavorite)).tolist(),
                      **_summary(r, rows, pb)})
    return pb.theta(np.asarray(es.result.xfavorite)), curve


def holdout(pb: Problem, theta: np.ndarray, n: int, seed: int, out: Path, run: Any) -> dict[str, Any]:
    """theta0 and the learned theta on ``n`` held-out seeds (same draws), deterministic switching."""
    if n < 1:
        return {}
    res = {}
    objs = {}
    for tag, th in (("hold0", pb.theta0), ("hold1", theta)):
        rows = run(_specs(pb, out, seed, "hold", 0, np.tile(th, (n, 1)), None, prefix=tag), tag)
        objs[tag] = np.array([value(pb.objective, r) if r.get("status") == "ok" else math.nan for r in rows])
        res[tag] = _summary(np.array([pb.reward(r) for r in rows]), rows, pb)
    diff = objs["hold1"] - objs["hold0"]
    return {"runs": n, "hand_tuned": res["hold0"], "learned": res["hold1"],
            "paired_diff_mean": _f(np.nanmean(diff)), "paired_diff_ci95": _ci(diff)}


def learned_yaml(pb: Problem, theta: np.ndarray, dest: Path) -> None:
    import yaml

    from corridor.scenario import apply_overrides

    data = apply_overrides(pb.raw, {**pb.after, **{k: float(v) for k, v in zip(pb.keys, theta, strict=True)}})
    data.pop("extends", None)
    dest.write_text(f"# {pb.path.name} with boundaries learned by run_scenario --learn\n"
                    + yaml.safe_dump(data, sort_keys=False))


def learn(scenario: str | Path, keys: str, objective: str, *, budget: int, method: str = "blrl",
          constraints: Sequence[str] = ("collisions == 0",), variant: str | None = None, holdout_runs: int = 20,
          seed: int | None = None, sets: Sequence[str] = (), out: str | Path | None = None, resume: bool = False,
          overwrite: bool = False, executor: str = "local", workers: int = 2, address: str | None = None,
          progress: bool = False, penalty: str = "count") -> dict[str, Any]:
    """Learn boundary parameters (see the module docstring); returns ``learn.json``'s content."""
    import pandas as pd

    from corridor.batchdir import manifest_for, open_batch_dir
    from corridor.estimate import write_json

    pb = problem(scenario, keys, objective, constraints, budget, method, variant, sets, penalty)
    if not isinstance(holdout_runs, int) or holdout_runs < 0:
        raise CorridorError(f"--holdout {holdout_runs}: must be a number of runs >= 0")
    if method == "ppo":
        from corridor import learn_ppo

        learn_ppo.check(pb, resume, executor)
    first = pb.sc.seed if seed is None else seed
    out_dir = Path(out) if out is not None else Path("results") / f"{pb.sc.name}-learn-{method}"
    settings = {"keys": pb.keys, "objective": objective, "constraints": list(constraints), "budget": budget,
                "method": method, "variant": pb.variant, "seed": first, "holdout": holdout_runs,
                **({"penalty": penalty} if penalty != "count" else {})}  # (count: the settings of older folders)
    bdir = open_batch_dir(out_dir, manifest_for(pb.sc.name, str(pb.path), {**pb.raw, "_learn": settings}, list(sets)),
                          resume, overwrite)
    all_rows: list[dict[str, Any]] = []

    def run(specs: list[Any], stage: Any) -> list[dict[str, Any]]:
        name = f"{stage:03d}" if isinstance(stage, int) else str(stage)
        rows = _run(specs, out_dir / ("stages" if isinstance(stage, int) else "holdout") / name, executor, workers,
                    address, progress)
        all_rows.extend({**r, "learn.stage": name} for r in rows)
        return rows

    try:
        if method == "ppo":
            return _learn_ppo(pb, settings, list(sets), budget, first, out_dir, run, holdout_runs, all_rows)
        theta, curve = (blrl if method == "blrl" else cma_es)(pb, budget, first, out_dir, run)
        data = {"kind": "learn", "scenario": pb.sc.name, "source": str(pb.path), **settings, "sets": list(sets),
                "theta0": dict(zip(pb.keys, pb.theta0.tolist(), strict=True)),
                "theta": dict(zip(pb.keys, theta.tolist(), strict=True)), "curve": curve,
                "training_runs": sum(c["runs"] for c in curve),
                "holdout": holdout(pb, theta, holdout_runs, first, out_dir, run)}
        write_json(out_dir / "learn.json", data)
        learned_yaml(pb, theta, out_dir / "learned.yaml")
        pd.DataFrame(all_rows).astype({"learn.stage": str}).to_parquet(out_dir / "runs.parquet", index=False)
        return data
    finally:
        bdir.close()


def _learn_ppo(pb: Problem, settings: dict[str, Any], sets: list[str], budget: int, seed: int, out_dir: Path,
               run: Any, holdout_runs: int, all_rows: list[dict[str, Any]]) -> dict[str, Any]:
    """--method ppo (corridor.learn_ppo): a policy instead of theta (no learned.yaml)."""
    import pandas as pd

    from corridor import learn_ppo
    from corridor.estimate import write_json

    switch = learn_ppo.check(pb, False, "local")
    curve, rows = learn_ppo.train(pb, budget, seed, out_dir, sets, switch)
    all_rows.extend(rows)
    hold, hold_rows = learn_ppo.holdout(pb, out_dir, holdout_runs, seed, sets, switch, run,
                                        {int(r["seed"]) for r in rows if r.get("seed") is not None})
    all_rows.extend(hold_rows)
    data = {"kind": "learn", "scenario": pb.sc.name, "source": str(pb.path), **settings, "sets": sets,
            "theta0": dict(zip(pb.keys, pb.theta0.tolist(), strict=True)), "theta": None,
            "policy": learn_ppo.POLICY, "normaliser": learn_ppo.NORMALISER, "switch": list(switch),
            "curve": curve, "training_runs": sum(c["runs"] for c in curve), "holdout": hold}
    write_json(out_dir / "learn.json", data)
    pd.DataFrame(all_rows).astype({"learn.stage": str}).to_parquet(out_dir / "runs.parquet", index=False)
    return data


def learn_lines(data: dict[str, Any]) -> list[str]:
    """The summary ``run_scenario --learn`` prints."""
    lines = [f"{data['scenario']} [{data['variant']}] --learn {data['method']}: {data['training_runs']} training runs"]
    for k, v0 in data["theta0"].items():
        if data["theta"] is None:  # ppo: a policy, not boundary parameters
            lines.append(f"  {k.split('.params.boundaries.', 1)[1]}: {v0:g} (hand-tuned; ppo learns a policy)")
        else:
            lines.append(f"  {k.split('.params.boundaries.', 1)[1]}: {v0:g} -> {data['theta'][k]:g}")
    if data.get("policy"):
        lines.append(f"  policy: {data['policy']} (+ {data['normaliser']}); no learned.yaml")
    for c in data["curve"]:
        lo, hi = c["objective_ci95"]
        ci = f" [{lo:.4g}, {hi:.4g}]" if lo is not None else ""
        lines.append(f"  stage {c['stage']}: objective {c['objective_mean']}{ci}, violating runs {c['violating_runs']}")
    h = data["holdout"]
    if h:
        lo, hi = h["paired_diff_ci95"]
        lines.append(f"  held-out ({h['runs']} seeds): hand-tuned {h['hand_tuned']['objective_mean']:.4g} "
                     f"({h['hand_tuned']['violating_runs']} violating), learned {h['learned']['objective_mean']:.4g} "
                     f"({h['learned']['violating_runs']} violating); learned - hand-tuned "
                     f"{h['paired_diff_mean']:.4g} [{lo}, {hi}]")
    return lines
