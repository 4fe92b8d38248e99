"""The summary table printed at the end of a batch: one line per variant."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from corridor.analysis.stats import clopper_pearson


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    ax = abs(x)
    return f"{x:.3g}" if ax < 1000 else f"{x:.0f}"


def summary_table(df: pd.DataFrame, key_metrics: list[str]) -> str:
    """Per variant: runs, errors, collisions, collision probability (95 % exact CI), metrics mean ± sd."""
    metrics = [m for m in key_metrics if m in df.columns]
    head = ["variant", "runs", "errors", "collisions", "P(collision) [95% CI]"] + metrics
    lines = []
    for variant, g in df.groupby("variant", sort=False):
        ok = g[g["status"] == "ok"]
        coll = ok["collisions"].fillna(0).astype(int) if "collisions" in ok else pd.Series(dtype=int)
        k, n = int((coll > 0).sum()), len(ok)
        lo, hi = clopper_pearson(k, n)
        row = [str(variant), str(len(g)), str(len(g) - n), str(int(coll.sum())),
               f"{k}/{n} [{_fmt(lo)}, {_fmt(hi)}]" if n else "-"]
        for m in metrics:
            v = pd.to_numeric(ok[m], errors="coerce").to_numpy(dtype=float)
            v = v[np.isfinite(v)]
            row.append(f"{_fmt(v.mean())} ± {_fmt(v.std(ddof=1))}" if len(v) > 1 else
                       (_fmt(v[0]) if len(v) else "-"))
        lines.append(row)
    widths = [max(len(r[i]) for r in [head, *lines]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    out += [fmt.format(*r) for r in lines]
    return "\n".join(out)
