"""Learning curves of ``run_scenario --learn`` folders: the objective per stage with its 95 % interval,
the runs that broke a constraint, and the held-out comparison, several methods in one figure.

    python -m corridor.analysis.learning_curve results/uav_encounter-learn-blrl results/uav_encounter-learn-cma \\
        --out learning_curve.svg [--held-out bench.json]   # bench.json: learn_benchmark.py holdout --json
"""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure


def _curve(data: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    c = data["curve"]
    runs = np.cumsum([s["runs"] for s in c])
    mean = np.array([np.nan if s["objective_mean"] is None else s["objective_mean"] for s in c])
    lo = np.array([np.nan if s["objective_ci95"][0] is None else s["objective_ci95"][0] for s in c])
    hi = np.array([np.nan if s["objective_ci95"][1] is None else s["objective_ci95"][1] for s in c])
    return runs, mean, lo, hi, np.array([s["violating_runs"] for s in c])


def _held_out_marks(ax: Any, rows: list[dict[str, Any]], folder: Path, name: str, color: Any) -> None:
    """The rows of ``tools/learn_benchmark.py holdout`` (its ``--json``) for ``folder``: the learned objective
    on the held-out seeds (95 % interval) at the training runs it took, with its violating runs."""
    for row in rows:
        if Path(row["folder"]).resolve() != Path(folder).resolve():
            continue
        m, lo, hi = row["learned_objective"]
        ax.errorbar([row["training_episodes"]], [m], yerr=[[m - lo], [hi - m]], fmt="*", color=color, markersize=11,
                    capsize=3, markeredgecolor="black",
                    label=f"{name}: held-out ({row['pairs']} seeds, {row['violating_learned']} runs breaking a constraint)")


def figure(folders: list[Path], held_out: list[dict[str, Any]] | None = None) -> Figure:
    """Objective (mean and 95 % interval per stage) and violating runs against training runs; ``held_out``:
    rows of ``tools/learn_benchmark.py holdout`` to mark (the hand-tuned one as a dashed line).

    The y-axis spans the stage means and the held-out marks (with a margin of half their range, at
    least 5 %): a stage of two or three runs has a t interval far wider than the curve, and its band
    then runs off the axis instead of flattening every curve."""
    fig = Figure(figsize=(8.0, 4.6), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    seen: list[float] = []  # the means and marks the y-axis spans
    if held_out:
        m0 = held_out[0]["hand_tuned_objective"][0]
        seen.extend([m0, *(r["learned_objective"][0] for r in held_out)])
        ax.axhline(m0, color="grey", ls="--", lw=1.0,
                   label=f"hand-tuned: held-out ({held_out[0]['pairs']} seeds, "
                         f"{held_out[0]['violating_hand_tuned']} runs breaking a constraint)")
    for folder in folders:
        data = json.loads((Path(folder) / "learn.json").read_text())
        runs, mean, lo, hi, viol = _curve(data)
        seen.extend(mean[np.isfinite(mean)])
        start = ", ".join(f"{k.rsplit('.', 1)[-1]} {v:g}" for k, v in data.get("theta0", {}).items())
        name = f"{data['method']} from {start}" if start else data["method"]
        line = ax.plot(runs, mean, marker="o", markersize=6 if len(runs) <= 60 else 2.5, lw=1.0 if len(runs) > 60 else 1.5,
                       label=f"{name} (training stages)")[0]
        ax.fill_between(runs, lo, hi, alpha=0.2, color=line.get_color())
        h = data.get("holdout") or {}
        if h:
            for key, style in (("hand_tuned", "s"), ("learned", "*")):
                seen.append(h[key]["objective_mean"])
                ax.plot([runs[-1] + 2], [h[key]["objective_mean"]], style, color=line.get_color(), markersize=9,
                        label=f"{name}: held-out {key.replace('_', '-')} ({h['runs']} seeds)")
        _held_out_marks(ax, held_out or [], Path(folder), name, line.get_color())
        ax2.bar(runs, viol, width=2.0, alpha=0.6, color=line.get_color())
    if seen:
        lo_y, hi_y = min(seen), max(seen)
        pad = max(0.5 * (hi_y - lo_y), 0.05 * max(abs(lo_y), abs(hi_y)), 1e-9)
        ax.set_ylim(lo_y - pad, hi_y + pad)
    ax.set_ylabel(f"objective: {data['objective']}")
    keys = ", ".join(k.split("boundaries.")[-1] for k in data["keys"])
    ax.set_title("\n".join(textwrap.wrap(f"{data['scenario']} [{data['variant']}]: learning {keys}", 90)), fontsize=9)
    ax.legend(fontsize=6, framealpha=0.7)
    ax2.set_ylabel("violating runs")
    ax2.set_xlabel("training runs")
    return fig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=Path("learning_curve.svg"))
    ap.add_argument("--held-out", type=Path, action="append", default=[],
                    help="a table of tools/learn_benchmark.py holdout --json to mark (repeatable)")
    args = ap.parse_args(argv)
    missing = [f for f in args.folders if not (f / "learn.json").is_file()]
    if missing:
        print(f"learning_curve: {missing[0]}: no learn.json (a run_scenario --learn folder?)")
        return 2
    bad = [f for f in args.held_out if not f.is_file()]
    if bad:
        print(f"learning_curve: --held-out {bad[0]}: no such file (learn_benchmark.py holdout --json writes it)")
        return 2
    rows = [r for f in args.held_out for r in json.loads(f.read_text())]
    figure(args.folders, rows or None).savefig(args.out)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
