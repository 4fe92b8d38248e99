"""The benchmark of learned mode boundaries (issue 28 part 4): held-out table, learning curves, theta scan.

    python tools/learn_benchmark.py holdout DIR_BLRL DIR_CMA DIR_PPO --holdout 200 --out results/bench \\
        [--metric hard_brakes --metric sep_min_h_m] [--plot curves.svg] [--workers 2]
    python tools/learn_benchmark.py checkpoints DIR_PPO --against DIR_BLRL --holdout 50 --out results/bench
    python tools/learn_benchmark.py scan SCAN_DIR ... --reference SCAN_DIR_OF_THE_START --x avoid_enter.dist_m \\
        --objective -path_ratio_mean --constraint 'nmac == 0' [--plot scan.svg]

``holdout`` reads ``run_scenario --learn`` folders of one problem (same scenario, variant, keys,
objective, constraints, ``--set`` and first seed; trained with any ``--holdout``) and runs, on ``N``
held-out seeds that training never used (the same seeds and ``randomize`` draws ``--learn``'s own
held-out comparison uses), the hand-tuned start theta0 once, every distinct learned theta once (a theta
equal to theta0 reuses its rows: same seed, same rows) and every PPO policy (deterministic actions, in
the Gymnasium environment).  It prints, per method: training episodes, theta, the held-out objective,
the paired difference learned - hand-tuned with its 95 % t interval, the runs that broke a constraint,
the paired difference of the reward (objective - penalty x broken constraints, what the learners maximise),
the paired difference of each ``--metric`` column, and the training episodes needed to reach 95 % of
the final objective (``episodes_to_95``, on the training stages; 0 when the learned theta is theta0).  Rows go to ``OUT/holdout/<tag>/``; a second call with the
same ``OUT`` re-uses the finished runs (resume).

``checkpoints`` runs the PPO policy saved after 4, 8, 16, 32 and every 48 training runs
(``DIR/checkpoints/epNNNNN``) and the final one on the first ``N`` held-out seeds, beside the hand-tuned
theta0 and the learned theta of a blrl/cma folder on the same seeds: PPO "matches" at the first
checkpoint with 0 runs breaking a constraint and a mean objective at least that of the learned theta.

``scan`` reads plain batches (``run_scenario --seed S --runs N --set KEY=V ...``, the same seeds in
every folder) and prints, per folder, the objective's paired difference against ``--reference`` with
its 95 % interval and the violating runs: the landscape the learners search, e.g. whether the start
sits on a plateau.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

SAME = ("scenario", "variant", "keys", "objective", "constraints", "sets", "seed", "penalty")
WINDOW = 3  # stages in the trailing mean of episodes_to_95


# ---- pure figures (tested) ---------------------------------------------------------------------------
def ci95(x: Sequence[float]) -> tuple[float, float, float]:
    """(mean, low, high): the 95 % t interval of the mean of the finite values (NaN when fewer than 2)."""
    from scipy import stats

    a = np.asarray(x, float)
    a = a[np.isfinite(a)]
    if len(a) < 2:
        return (float(a.mean()) if len(a) else math.nan, math.nan, math.nan)
    h = float(stats.t.ppf(0.975, len(a) - 1) * a.std(ddof=1) / math.sqrt(len(a)))
    return float(a.mean()), float(a.mean() - h), float(a.mean() + h)


def episodes_to_95(curve: list[dict[str, Any]], window: int = WINDOW) -> int | None:
    """Training episodes until the trailing ``window``-stage mean of the stage objective first reaches
    95 % of the way from the first stage's objective to the final trailing mean; None when the final
    trailing mean is not above the first stage (nothing gained to reach)."""
    means = np.array([math.nan if c.get("objective_mean") is None else c["objective_mean"] for c in curve], float)
    runs = np.cumsum([c["runs"] for c in curve])
    if len(means) == 0 or not np.isfinite(means[0]):
        return None
    smooth = np.array([np.nanmean(means[max(0, k - window + 1):k + 1]) for k in range(len(means))])
    start, final = means[0], smooth[-1]
    if not final > start:
        return None
    target = start + 0.95 * (final - start)
    k = int(np.argmax(smooth >= target))
    return int(runs[k])


def paired(a: dict[int, float], b: dict[int, float]) -> tuple[float, float, float, int]:
    """(mean, low, high, pairs) of b - a over the keys (seeds) both have."""
    common = sorted(set(a) & set(b))
    m, lo, hi = ci95([b[k] - a[k] for k in common])
    return m, lo, hi, len(common)


def check_same(datas: list[dict[str, Any]], names: list[str]) -> None:
    """The folders must hold one problem; else one line naming the field that differs."""
    from corridor.errors import CorridorError

    def text(d: dict[str, Any], field: str) -> str:  # an expression's spacing does not make another problem
        v = json.dumps(d.get(field), sort_keys=True)
        return "".join(v.split()) if field in ("objective", "constraints") else v

    for field in SAME:
        values = {text(d, field) for d in datas}
        if len(values) > 1:
            raise CorridorError(f"learn_benchmark: the folders learn different problems ({field} differs: "
                                f"{', '.join(names)})")


def fmt_ci(m: float, lo: float, hi: float, digits: int = 4) -> str:
    if not math.isfinite(m):
        return "-"
    if not math.isfinite(lo):
        return f"{m:+.{digits}f}"
    return f"{m:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]"


# ---- held-out ------------------------------------------------------------------------------------------
def load_learn(folder: Path) -> dict[str, Any]:
    from corridor.errors import CorridorError

    f = folder / "learn.json"
    if not f.is_file():
        raise CorridorError(f"learn_benchmark: {folder}: no learn.json (a run_scenario --learn folder?)")
    return json.loads(f.read_text())


def problem_of(data: dict[str, Any]) -> Any:
    from corridor.learn import problem

    return problem(data["source"], ",".join(data["keys"]), data["objective"], data["constraints"], data["budget"],
                   data["method"], data["variant"], data["sets"], data.get("penalty", "count"))


def _theta_rows(pb: Any, theta: np.ndarray, n: int, seed: int, out: Path, tag: str, workers: int) -> list[dict[str, Any]]:
    from corridor.learn import _run
    from corridor.learn_core import specs

    sp = specs(pb, out, seed, "hold", 0, np.tile(theta, (n, 1)), None, prefix="hold")
    return _run(sp, out / "holdout" / tag, "local", workers, None, False)


_WORKER: dict[str, Any] = {}  # per policy-evaluating process: the problem of its folder


def _policy_run(folder: str, seed: int, draws: dict[str, Any], policy: str | None = None) -> dict[str, Any]:
    """One held-out run of the PPO policy of the --learn ``folder`` (in a worker process); ``policy`` is the
    folder of the policy files when it is not ``folder`` itself (a checkpoint)."""
    from corridor.learn_ppo import evaluate_policy

    if _WORKER.get("folder") != folder:
        data = load_learn(Path(folder))
        _WORKER.update(folder=folder, data=data, pb=problem_of(data))
    data = _WORKER["data"]
    return evaluate_policy(Path(policy or folder), _WORKER["pb"], list(data["sets"]),
                           tuple(data["switch"]), seed, draws)


def _policy_rows(pb: Any, folder: Path, n: int, seed: int, out: Path, tag: str, workers: int,
                 policy: Path | None = None) -> list[dict[str, Any]]:
    """The PPO policy on the held-out seeds and draws (``workers`` processes); finished rows are kept in
    ``rows.parquet`` as they come (a second call runs only the missing ones).  ``policy``: a checkpoint's
    folder instead of the final policy in ``folder``."""
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import pandas as pd

    from corridor.learn_core import specs

    store = out / "holdout" / tag / "rows.parquet"
    store.parent.mkdir(parents=True, exist_ok=True)
    done = {r["run_id"]: r for r in pd.read_parquet(store, partitioning=None).to_dict("records")} if store.is_file() else {}
    hold = specs(pb, out, seed, "hold", 0, np.tile(pb.theta0, (n, 1)), None, prefix="hold")
    todo = [s for s in hold if s.run_id not in done]
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per process: torch's own threads would contend
    with ProcessPoolExecutor(max(1, workers), mp_context=mp.get_context("spawn")) as ex:
        futures = {ex.submit(_policy_run, str(folder), s.seed, s.draws, None if policy is None else str(policy)): s
                   for s in todo}
        for fut in as_completed(futures):
            s = futures[fut]
            done[s.run_id] = {**fut.result(), "run_id": s.run_id, "seed": s.seed}
            pd.DataFrame(list(done.values())).to_parquet(store, index=False)
    return [done[s.run_id] for s in hold]


def training_seeds(folder: Path) -> set[int]:
    """The seeds of a --learn folder's training runs (its ``runs.parquet`` rows of a numbered stage)."""
    import pandas as pd

    from corridor.errors import CorridorError

    f = folder / "runs.parquet"
    if not f.is_file():
        raise CorridorError(f"learn_benchmark: {folder}: no runs.parquet (the training did not finish?)")
    df = pd.read_parquet(f, columns=["seed", "learn.stage"], partitioning=None)
    train = df[df["learn.stage"].astype(str).str.fullmatch(r"\d+") & df["seed"].notna()]
    return {int(x) for x in train["seed"]}


def hand_tuned_theta(pb: Any, values: Sequence[str]) -> np.ndarray:
    """theta0 with ``KEY=VALUE`` replaced (``--hand-tuned``: the start of the learners was not the hand-tuned
    controller, e.g. a boundary that is off by default, ``open_ahead.dist_m=0``); one line on a bad one."""
    from corridor.errors import CorridorError

    th = pb.theta0.astype(float).copy()
    for item in values:
        key, sep, text = item.partition("=")
        idx = [i for i, k in enumerate(pb.keys) if k == key or k.endswith(f".boundaries.{key}")]
        try:
            v = float(text)
        except ValueError:
            idx = []
        if not sep or len(idx) != 1:
            raise CorridorError(f"learn_benchmark: --hand-tuned {item!r}: KEY=NUMBER with KEY one of the learned "
                                f"keys ({', '.join(k.split('.boundaries.', 1)[-1] for k in pb.keys)})")
        th[idx[0]] = v
    return th


def holdout_table(folders: list[Path], n: int, out: Path, metrics: Sequence[str], workers: int,
                  hand: Sequence[str] = ()) -> list[dict[str, Any]]:
    """One dict per folder (method): the held-out figures against the hand-tuned theta0 (``hand``: with
    these ``KEY=VALUE`` instead of the learners' start)."""
    from corridor.learn_core import specs

    datas = [load_learn(f) for f in folders]
    check_same(datas, [str(f) for f in folders])
    pb = problem_of(datas[0])
    seed = int(datas[0]["seed"])
    held = {int(s.seed) for s in specs(pb, out, seed, "hold", 0, np.tile(pb.theta0, (n, 1)), None, prefix="hold")}
    theta_hand = hand_tuned_theta(pb, hand)
    base = _theta_rows(pb, theta_hand, n, seed, out, "hand_tuned" if not hand else "hand_tuned-" + "-".join(hand), workers)
    cache: dict[tuple[float, ...], list[dict[str, Any]]] = {tuple(np.round(theta_hand, 9)): base}
    table = []
    for folder, data in zip(folders, datas, strict=True):
        tag = f"{data['method']}-{folder.name}"
        key: tuple[float, ...] = ()
        if data["theta"] is None:
            rows = _policy_rows(pb, folder, n, seed, out, tag, workers)
            theta = "policy"
        else:
            th = np.array([data["theta"][k] for k in data["keys"]])
            key = tuple(np.round(th, 9))
            if key not in cache:
                cache[key] = _theta_rows(pb, th, n, seed, out, tag, workers)
            rows = cache[key]
            theta = ", ".join(f"{k.split('.params.boundaries.', 1)[1]} {v:.4g}" for k, v in zip(data["keys"], th, strict=True))
        unchanged = data["theta"] is not None and key == tuple(np.round(theta_hand, 9))
        table.append({"method": data["method"], "folder": str(folder), "training_episodes": data["training_runs"],
                      "overlap_training_seeds": len(held & training_seeds(folder)),
                      "theta": theta, "episodes_to_95": 0 if unchanged else episodes_to_95(data["curve"]),
                      **compare(pb, base, rows, metrics)})
    return table


def checkpoint_table(ppo: Path, against: Path, n: int, out: Path, workers: int) -> list[dict[str, Any]]:
    """The PPO policy after each saved number of training runs (``DIR/checkpoints/epNNNNN`` and the final one)
    on the first ``n`` held-out seeds, against the hand-tuned theta0 and the learned theta of ``against`` (a
    blrl/cma folder of the same problem) on the same seeds and draws: when, if ever, PPO matches it."""
    from corridor.errors import CorridorError
    from corridor.learn_ppo import CHECKPOINTS
    from corridor.objective import value

    data, ref = load_learn(ppo), load_learn(against)
    check_same([data, ref], [str(ppo), str(against)])
    if data["theta"] is not None or ref["theta"] is None:
        raise CorridorError(f"learn_benchmark checkpoints: {ppo} must be a --method ppo folder and {against} "
                            "a blrl or cma folder")
    pb = problem_of(data)
    seed = int(data["seed"])
    base = _theta_rows(pb, pb.theta0, n, seed, out, "hand_tuned", workers)
    th = np.array([ref["theta"][k] for k in ref["keys"]])
    same_as_start = tuple(np.round(th, 9)) == tuple(np.round(pb.theta0, 9))
    rows_ref = base if same_as_start else _theta_rows(pb, th, n, seed, out, f"{ref['method']}-{against.name}", workers)
    points = sorted((int(p.name[2:]), p) for p in (ppo / CHECKPOINTS).glob("ep*") if p.name[2:].isdigit())
    points.append((int(data["training_runs"]), ppo))
    obj = lambda r: value(pb.objective, r)  # noqa: E731
    o_ref = _by_seed(rows_ref, obj)
    table = []
    for episodes, folder in points:
        tag = f"ppo-{ppo.name}" if folder == ppo else f"ppo-{ppo.name}-ep{episodes:05d}"
        rows = _policy_rows(pb, ppo, n, seed, out, tag, workers, None if folder == ppo else folder)
        o = _by_seed(rows, obj)
        common = sorted(set(o) & set(o_ref))
        bad = violating(pb, rows)
        table.append({"episodes": episodes, **compare(pb, base, rows, ()),
                      "against_objective": ci95([o_ref[k] for k in common]),
                      "paired_diff_against": paired(o_ref, o)[:3], "violating_against": violating(pb, rows_ref),
                      "matches": bool(common) and bad == 0 and float(np.mean([o[k] for k in common]))
                      >= float(np.mean([o_ref[k] for k in common]))})
    return table


def print_checkpoints(table: list[dict[str, Any]], against: str) -> None:
    t0 = table[0]
    print(f"held-out: {t0['pairs']} seeds; hand-tuned {fmt_ci(*t0['hand_tuned_objective'])} "
          f"({t0['violating_hand_tuned']} violating); {against} {fmt_ci(*t0['against_objective'])} "
          f"({t0['violating_against']} violating)")
    head = ["PPO training runs", "held-out objective", "ppo - hand-tuned [95 % CI]", f"ppo - {against} [95 % CI]",
            "violating runs", "matches"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for t in table:
        print("| " + " | ".join([str(t["episodes"]), fmt_ci(*t["learned_objective"]), fmt_ci(*t["paired_diff"]),
                                 fmt_ci(*t["paired_diff_against"]), str(t["violating_learned"]),
                                 "yes" if t["matches"] else "no"]) + " |")
    first = next((t["episodes"] for t in table if t["matches"]), None)
    print(f"first match: {first if first is not None else 'none'} training runs")


def _by_seed(rows: list[dict[str, Any]], f: Any) -> dict[int, float]:
    return {int(r["seed"]): f(r) for r in rows if r.get("status", "ok") == "ok" and r.get("seed") is not None}


def violating(pb: Any, rows: list[dict[str, Any]]) -> int:
    """Runs that broke a constraint, or did not finish."""
    from corridor.objective import violations

    return sum(r.get("status", "ok") != "ok" or violations(pb.constraints, r) > 0 for r in rows)


def compare(pb: Any, base: list[dict[str, Any]], rows: list[dict[str, Any]], metrics: Sequence[str]) -> dict[str, Any]:
    """Objective and ``metrics`` of ``rows`` against ``base``, paired by seed."""
    from corridor.objective import value

    obj = lambda r: value(pb.objective, r)  # noqa: E731
    o0, o1 = _by_seed(base, obj), _by_seed(rows, obj)
    m, lo, hi, pairs = paired(o0, o1)
    res = {"pairs": pairs, "hand_tuned_objective": ci95(list(o0.values())), "learned_objective": ci95(list(o1.values())),
           "paired_diff": (m, lo, hi), "violating_hand_tuned": violating(pb, base),
           "violating_learned": violating(pb, rows), "errors": sum(r.get("status", "ok") != "ok" for r in rows)}
    res["paired_diff_reward"] = paired(_by_seed(base, pb.reward), _by_seed(rows, pb.reward))[:3]
    for col in metrics:
        f = lambda r, c=col: float(r.get(c, math.nan))  # noqa: E731
        res[f"paired_diff.{col}"] = paired(_by_seed(base, f), _by_seed(rows, f))[:3]
    return res


def print_holdout(table: list[dict[str, Any]], metrics: Sequence[str]) -> None:
    t0 = table[0]
    m0 = t0["hand_tuned_objective"]
    print(f"held-out: {t0['pairs']} seeds; hand-tuned objective {fmt_ci(*m0)}, violating runs {t0['violating_hand_tuned']}")
    print("held-out seeds also drawn in training: "
          + ", ".join(f"{t['method']} {t['overlap_training_seeds']}" for t in table))
    head = ["method", "train ep.", "ep. to 95 %", "theta", "held-out objective", "learned - hand-tuned [95 % CI]",
            "violating", "reward: learned - hand-tuned", *[f"d {c}" for c in metrics]]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for t in table:
        e95 = "-" if t["episodes_to_95"] is None else str(t["episodes_to_95"])
        cells = [t["method"], str(t["training_episodes"]), e95, t["theta"], fmt_ci(*t["learned_objective"]),
                 fmt_ci(*t["paired_diff"]), f"{t['violating_hand_tuned']} -> {t['violating_learned']}",
                 fmt_ci(*t["paired_diff_reward"]),
                 *[fmt_ci(*t[f"paired_diff.{c}"], digits=3) for c in metrics]]
        print("| " + " | ".join(cells) + " |")


# ---- scan ---------------------------------------------------------------------------------------------
def scan_rows(folder: Path) -> tuple[dict[str, str], list[dict[str, Any]]]:
    """(``--set`` values by their short key, rows) of a plain batch folder."""
    import pandas as pd

    from corridor.errors import CorridorError

    if not (folder / "runs.parquet").is_file():
        raise CorridorError(f"learn_benchmark scan: {folder}: no runs.parquet (a run_scenario batch folder?)")
    sets = json.loads((folder / "batch.json").read_text()).get("sets", []) if (folder / "batch.json").is_file() else []
    short = {s.split("=", 1)[0].split(".params.boundaries.", 1)[-1]: s.split("=", 1)[1] for s in sets}
    return short, pd.read_parquet(folder / "runs.parquet").to_dict("records")


def scan_table(folders: list[Path], reference: Path, objective: str, constraints: Sequence[str],
               metrics: Sequence[str] = ()) -> list[dict[str, Any]]:
    from corridor.objective import Expression, value, violations

    obj = Expression(objective, "--objective")
    cons = [Expression(c, "--constraint") for c in constraints]
    _, ref = scan_rows(reference)
    f = lambda r: value(obj, r)  # noqa: E731
    o0 = _by_seed(ref, f)
    out = []
    for folder in folders:
        sets, rows = scan_rows(folder)
        m, lo, hi, pairs = paired(o0, _by_seed(rows, f))
        t = {"folder": str(folder), "sets": sets, "objective": ci95(list(_by_seed(rows, f).values())),
             "paired_diff": (m, lo, hi), "pairs": pairs,
             "violating": sum(violations(cons, r) > 0 for r in rows if r.get("status", "ok") == "ok")}
        for col in metrics:
            g = lambda r, c=col: float(r.get(c, math.nan))  # noqa: E731
            t[f"paired_diff.{col}"] = paired(_by_seed(ref, g), _by_seed(rows, g))[:3]
        out.append(t)
    return out


def scan_figure(table: list[dict[str, Any]], x: str, objective: str, metrics: Sequence[str] = ()) -> Any:
    """Paired differences against the reference (95 % intervals) vs the ``x`` set value: the objective,
    then each metric; one line per combination of the other set values (keys equal to ``x`` in every
    folder move with it and are left out of the label)."""
    from matplotlib.figure import Figure

    panels = [("paired_diff", f"{objective}")] + [(f"paired_diff.{c}", c) for c in metrics]
    fig = Figure(figsize=(7.0, 2.2 + 1.8 * len(panels)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
    on_x = [t for t in table if x in t["sets"]]
    tied = {k for k in on_x[0]["sets"] if all(t["sets"].get(k) == t["sets"][x] for t in on_x)} if on_x else set()
    groups: dict[str, list[dict[str, Any]]] = {}
    for t in on_x:
        label = ", ".join(f"{k} {v}" for k, v in sorted(t["sets"].items()) if k not in tied)
        groups.setdefault(label or x, []).append(t)
    for ax, (field, name) in zip(axes, panels, strict=True):
        for label, ts in groups.items():
            ts = sorted(ts, key=lambda t: float(t["sets"][x]))
            xs = np.array([float(t["sets"][x]) for t in ts])
            m, lo, hi = (np.array([t[field][i] for t in ts]) for i in range(3))
            ax.errorbar(xs, m, yerr=[m - lo, hi - m], marker="o", capsize=3, label=label)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_ylabel(f"{name}\n(paired diff., 95 % CI)", fontsize=8)
    axes[0].set_xscale("log")
    axes[-1].set_xlabel(x)
    axes[0].legend(fontsize=7)
    return fig


# ---- command line -------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    from corridor.errors import CorridorError

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    h = sub.add_parser("holdout", help="held-out table of --learn folders (one problem)")
    h.add_argument("folders", nargs="+", type=Path)
    h.add_argument("--holdout", type=int, default=200, help="held-out seeds (default 200)")
    h.add_argument("--out", type=Path, required=True, help="folder for the held-out rows (re-used on a second call)")
    h.add_argument("--metric", action="append", default=[], help="a column whose paired difference to print")
    h.add_argument("--workers", type=int, default=2)
    h.add_argument("--plot", type=Path, help="learning curves of the folders in one SVG")
    h.add_argument("--json", type=Path, help="write the table as JSON")
    h.add_argument("--hand-tuned", action="append", default=[], metavar="KEY=VALUE",
                   help="the hand-tuned controller's value of a learned key where the learners started elsewhere")
    c = sub.add_parser("checkpoints", help="a PPO folder's checkpoints against a blrl/cma result on held-out seeds")
    c.add_argument("ppo", type=Path)
    c.add_argument("--against", type=Path, required=True, help="the blrl or cma folder PPO must match")
    c.add_argument("--holdout", type=int, default=50, help="held-out seeds (the first N of holdout's; default 50)")
    c.add_argument("--out", type=Path, required=True, help="folder for the held-out rows (shared with holdout)")
    c.add_argument("--workers", type=int, default=2)
    c.add_argument("--json", type=Path, help="write the table as JSON")
    s = sub.add_parser("scan", help="objective against a boundary parameter, paired with a reference batch")
    s.add_argument("folders", nargs="+", type=Path)
    s.add_argument("--reference", type=Path, required=True)
    s.add_argument("--objective", required=True)
    s.add_argument("--constraint", action="append", default=[])
    s.add_argument("--x", required=True, help="the --set key on the x axis (boundary.param)")
    s.add_argument("--metric", action="append", default=[], help="a column whose paired difference to show too")
    s.add_argument("--plot", type=Path)
    from corridor.cli import _glue_expressions

    args = ap.parse_args(_glue_expressions(list(sys.argv[1:] if argv is None else argv)))
    try:
        if args.cmd == "holdout":
            if args.holdout < 2:
                raise CorridorError(f"--holdout {args.holdout}: need at least 2 seeds for an interval")
            for f in args.folders:
                load_learn(f)  # one line before any run
            table = holdout_table(args.folders, args.holdout, args.out, args.metric, args.workers, args.hand_tuned)
            print_holdout(table, args.metric)
            if args.json:
                args.json.write_text(json.dumps(table, indent=1))
            if args.plot:
                from corridor.analysis.learning_curve import figure

                figure(args.folders, table).savefig(args.plot)
                print(args.plot)
        elif args.cmd == "checkpoints":
            if args.holdout < 2:
                raise CorridorError(f"--holdout {args.holdout}: need at least 2 seeds for an interval")
            table = checkpoint_table(args.ppo, args.against, args.holdout, args.out, args.workers)
            print_checkpoints(table, load_learn(args.against)["method"])
            if args.json:
                args.json.write_text(json.dumps(table, indent=1))
        else:
            table = scan_table(args.folders, args.reference, args.objective, args.constraint, args.metric)
            print(f"{'set values':60s} {'pairs':>5s} {'objective':>26s} {'paired diff [95 % CI]':>34s} violating")
            for t in table:
                label = ", ".join(f"{k}={v}" for k, v in t["sets"].items())
                extra = "".join(f"  d {c} {fmt_ci(*t[f'paired_diff.{c}'], digits=2)}" for c in args.metric)
                print(f"{label:60s} {t['pairs']:5d} {fmt_ci(*t['objective']):>26s} {fmt_ci(*t['paired_diff']):>34s} "
                      f"{t['violating']}{extra}")
            if args.plot:
                scan_figure(table, args.x, args.objective, args.metric).savefig(args.plot)
                print(args.plot)
    except CorridorError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
