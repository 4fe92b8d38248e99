"""The merging sweep's heat maps (``scenarios/sweeps/merging_sweep.yaml``): where cooperative merging gains.

The sweep's variants are named ``p<penetration %>_r<ramp demand veh/h>_L<acceleration lane m>``
(``tools/merging_sweep.py`` writes them); ``p0`` is the human baseline of its (ramp demand, lane) cell.
Each cell with a penetration above 0 gets the paired difference (same seed, so the same demand draws)
of a metric to the ``p0`` variant of its row and panel: mean and 95 % Student-t interval over seeds.
The heat map shows the mean, and marks with ``*`` the cells whose interval excludes 0.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from corridor.analysis.stats import mean_ci

NAME = re.compile(r"^p(\d+)_r(\d+)_L(\d+)$")
METRICS = (("delay_mean_s", "mean delay [s]"), ("hard_brakes", "hard brakes"),
           ("energy_proxy_mean", "energy proxy"))


@dataclass(frozen=True)
class Cell:
    """One penetration x ramp demand x lane cell's paired difference to its human baseline."""

    penetration_pct: int
    ramp_vph: int
    lane_m: int
    pairs: int
    mean: float
    lo: float
    hi: float

    @property
    def significant(self) -> bool:
        """The interval excludes 0 (a zero-width interval, two equal differences, is no evidence)."""
        return math.isfinite(self.lo) and self.hi > self.lo and (self.lo > 0 or self.hi < 0)


def sweep_cells(ok: pd.DataFrame, metric: str) -> list[Cell]:
    """The cells of the sweep's ``ok`` runs for ``metric`` (empty if the batch is not the sweep)."""
    if metric not in ok or "seed" not in ok:
        return []
    parsed = {v: NAME.match(str(v)) for v in dict.fromkeys(ok["variant"])}
    grid = {v: tuple(int(x) for x in m.groups()) for v, m in parsed.items() if m}
    cells = []
    for v, (p, r, lane) in grid.items():
        base = f"p0_r{r}_L{lane}"
        if p == 0 or base not in grid:
            continue
        d = _by_seed(ok, v, metric).sub(_by_seed(ok, base, metric), fill_value=np.nan).dropna()
        m, lo, hi = mean_ci(d.to_numpy(dtype=float))
        cells.append(Cell(p, r, lane, len(d), m, lo, hi))
    return cells


def _by_seed(ok: pd.DataFrame, variant: str, metric: str) -> pd.Series:
    g = ok[ok["variant"].astype(str) == variant]
    return pd.Series(pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float), index=g["seed"].to_numpy())


def draw(cells: list[Cell], title: str, fig: object) -> None:
    """One panel per acceleration-lane length: ramp demand (rows) x penetration (columns), coloured by
    the mean paired difference (blue: lower than the humans, red: higher), ``*`` where significant."""
    lanes = sorted({c.lane_m for c in cells})
    pens = sorted({c.penetration_pct for c in cells})
    ramps = sorted({c.ramp_vph for c in cells})
    lim = max((abs(c.mean) for c in cells if math.isfinite(c.mean)), default=1.0) or 1.0
    axes = fig.subplots(1, len(lanes), squeeze=False)[0]  # type: ignore[attr-defined]
    mesh = None
    for ax, lane in zip(axes, lanes):
        grid = np.full((len(ramps), len(pens)), np.nan)
        for c in cells:
            if c.lane_m == lane:
                i, j = ramps.index(c.ramp_vph), pens.index(c.penetration_pct)
                grid[i, j] = c.mean
                ax.text(j, i, f"{c.mean:.2g}{'*' if c.significant else ''}", ha="center", va="center", fontsize=7)
        mesh = ax.imshow(grid, cmap="coolwarm", vmin=-lim, vmax=lim, aspect="auto", origin="lower", gid="heatmap")
        ax.set_xticks(range(len(pens)), [f"{p} %" for p in pens])
        ax.set_yticks(range(len(ramps)), [str(r) for r in ramps])
        ax.grid(False)
        ax.set(title=f"acceleration lane {lane} m", xlabel="penetration", ylabel="ramp demand [veh/h]")
    if mesh is not None:
        fig.colorbar(mesh, ax=list(axes), label=title)  # type: ignore[attr-defined]


def sweep_section(ok: pd.DataFrame) -> list[str]:
    """The report's heat maps, one per metric the runs have (none if the batch is not the sweep)."""
    from corridor.analysis.plots import RC, svg

    out = []
    for metric, label in METRICS:
        cells = sweep_cells(ok, metric)
        if not cells:
            continue
        import matplotlib
        from matplotlib.figure import Figure

        matplotlib.rcParams.update(RC)
        fig = Figure(figsize=(10.0, 3.2), layout="constrained")
        draw(cells, f"{label}: cooperative - human", fig)
        out.append(svg(fig, "sweep"))
    if not out:
        return []
    seeds = int(ok["seed"].nunique())
    return ["<h2>Merging sweep: paired gain of cooperative merging</h2>",
            f"<p>Per cell: cooperative (v2x_cps) minus the human baseline (penetration 0) of the same ramp "
            f"demand and acceleration lane, same seeds ({seeds} seeds), mean; * marks a 95 % interval that "
            "excludes 0. Negative delay / hard brakes / energy is a gain.</p>", *out]
