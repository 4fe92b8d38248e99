"""The report's charts, drawn with matplotlib and embedded as inline SVG (the report stays one
self-contained HTML file).

Text stays text (``svg.fonttype = none``: titles, labels and legends can be searched), dense layers
(a time-space diagram's thousands of samples, a heatmap's cells) are rasterized inside the SVG, and
every drawn data layer carries an id (matplotlib's ``gid``) naming what it is, which tests count:
``series:<label>`` (a line), ``band:<label>`` (an interquartile band), ``warmup`` (the warm-up span),
``ref:<label>`` (a reference line), ``track:<label>``, ``points:<label>``, ``bar:<label>``,
``heatmap``, ``timespace``.  Figures are ``matplotlib.figure.Figure`` objects (no pyplot state).
"""

from __future__ import annotations

import html
import io
import math
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

RC = {"svg.fonttype": "none", "font.size": 9, "axes.titlesize": 10, "axes.grid": True, "grid.alpha": 0.3}
WIDE, TALL = (7.0, 3.0), (7.0, 4.2)  # [in] figure sizes
SPEED_CMAP = "RdYlGn"  # red: stopped, green: free flow


def figure(size: tuple[float, float] = WIDE, ncols: int = 1, **kw: object) -> tuple[Figure, np.ndarray]:
    import matplotlib

    matplotlib.rcParams.update(RC)
    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(1, ncols, squeeze=False, **kw)[0]
    return fig, axes


def svg(fig: Figure, cls: str) -> str:
    """The figure as an inline ``<svg>`` inside ``<figure class="plot {cls}">``."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", dpi=110)
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    return f'<figure class="plot {html.escape(cls)}">{text}</figure>'


SIDE_LEGEND_MAX = 16  # entries that fit beside a WIDE figure's axes; more go below it, in columns
BELOW_COLUMNS, ROW_IN = 4, 0.16  # columns of a legend below the axes; [in] the figure grows per row


def _legend(ax: object) -> None:
    handles, labels = ax.get_legend_handles_labels()  # type: ignore[attr-defined]
    if not labels:
        return
    if len(labels) <= SIDE_LEGEND_MAX:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)  # type: ignore[attr-defined]
        return
    # a sweep's dozens of variants: beside the axes they squeeze them to nothing, so they go below
    fig = ax.figure  # type: ignore[attr-defined]
    width_in, height_in = fig.get_size_inches()
    fig.set_size_inches(width_in, height_in + ROW_IN * math.ceil(len(labels) / BELOW_COLUMNS))
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=BELOW_COLUMNS,  # type: ignore[attr-defined]
              frameon=False)


def line_chart(series: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str, x_label: str, y_label: str,
               hlines: Sequence[tuple[float, str]] = (), dashed: Sequence[bool] | None = None,
               cls: str = "lines") -> str:
    """One line per (label, t, v) series, plus labelled horizontal reference lines."""
    fig, (ax,) = figure()
    for i, (label, t, v) in enumerate(series):
        style = "--" if (dashed[i] if dashed else i >= 10) else "-"
        ax.plot(np.asarray(t, float), np.asarray(v, float), style, lw=1.2, label=label, gid=f"series:{label}")
    _hlines(ax, hlines)
    ax.set(title=title, xlabel=x_label, ylabel=y_label)
    _legend(ax)
    return svg(fig, cls)


def _hlines(ax: object, hlines: Sequence[tuple[float, str]]) -> None:
    for y, label in hlines:
        ax.axhline(y, color="#b00", ls=":", lw=1, label=label, gid=f"ref:{label}")  # type: ignore[attr-defined]


def band_chart(series: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]], title: str,
               x_label: str, y_label: str, warmup_s: float = 0.0, hlines: Sequence[tuple[float, str]] = (),
               cls: str = "bands") -> str:
    """Per variant (label, t, median, q25, q75, n runs): the median line and its interquartile band;
    the warm-up (not measured) is shaded grey."""
    fig, (ax,) = figure()
    if warmup_s > 0:
        ax.axvspan(0.0, warmup_s, color="#999", alpha=0.18, lw=0, label=f"warm-up ({warmup_s:g} s)", gid="warmup")
    for i, (label, t, med, lo, hi, n) in enumerate(series):
        colour = f"C{i % 10}"
        ax.fill_between(t, lo, hi, color=colour, alpha=0.2, lw=0, gid=f"band:{label}")
        ax.plot(t, med, "-", color=colour, lw=1.3, label=f"{label} (median, n={n})", gid=f"series:{label}")
    _hlines(ax, hlines)
    ax.set(title=title, xlabel=x_label, ylabel=y_label)
    _legend(ax)
    return svg(fig, cls)


def heatmap(rows: Sequence[str], t_edges: np.ndarray, values: np.ndarray, title: str, x_label: str,
            unit: str, vmax: float) -> str:
    """A rows x time grid (``values[i, j]`` spans ``t_edges[j]..t_edges[j+1]``) coloured by speed."""
    fig, (ax,) = figure((7.0, 0.8 + 0.22 * max(len(rows), 4)))
    grid = np.ma.masked_invalid(np.asarray(values, float))
    mesh = ax.pcolormesh(t_edges, np.arange(len(rows) + 1), grid, cmap=SPEED_CMAP, vmin=0.0, vmax=vmax,
                         rasterized=True, gid="heatmap")
    ax.set_facecolor("#ddd")
    ax.set_yticks(np.arange(len(rows)) + 0.5, list(rows), fontsize=7)
    ax.invert_yaxis()
    ax.grid(False)
    ax.set(title=title, xlabel=x_label)
    fig.colorbar(mesh, ax=ax, label=unit)
    return svg(fig, "heatmap")


def scatter_chart(x: np.ndarray, y: np.ndarray, curves: Sequence[tuple[str, np.ndarray, np.ndarray]],
                  title: str, x_label: str, y_label: str, cls: str) -> str:
    """Points with model curves drawn over them."""
    fig, (ax,) = figure()
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    ax.plot(x[ok], y[ok], "o", ms=2.5, alpha=0.4, label=f"detector points (n={int(ok.sum())})", gid="points:detector")
    for i, (label, cx, cy) in enumerate(curves):
        ax.plot(cx, cy, "-" if i == 0 else "--", color=("C3", "C2", "C4")[i % 3], label=label, gid=f"series:{label}")
    ax.set(title=title, xlabel=x_label, ylabel=y_label)
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    _legend(ax)
    return svg(fig, cls)


def _tracks(ax: object, tracks: Sequence[tuple[str, np.ndarray, np.ndarray]], gid: bool = True) -> None:
    for i, (label, x, y) in enumerate(tracks):
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        colour, style = f"C{i % 10}", "-" if i < 10 else "--"
        ax.plot(x, y, style, color=colour, lw=1.2, label=label if gid else None,  # type: ignore[attr-defined]
                gid=f"track:{label}" if gid else None)
        if len(ok):
            ax.plot(x[ok[0]], y[ok[0]], "o", color=colour, ms=4)  # type: ignore[attr-defined]
            ax.plot(x[ok[-1]], y[ok[-1]], "s", color=colour, ms=4)  # type: ignore[attr-defined]


def track_chart(tracks: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str, x_label: str, y_label: str,
                cls: str = "tracks", zoom: tuple[float, float, float] | None = None) -> str:
    """Top-down paths at one scale on both axes (a circle marks the start, a square the end); with
    ``zoom = (x, y, half-width)`` a second panel shows the square around (x, y) (the encounter)."""
    fig, axes = figure((9.0, 4.2) if zoom else TALL, ncols=2 if zoom else 1)
    _tracks(axes[0], tracks)
    axes[0].set(title=title, xlabel=x_label, ylabel=y_label)
    axes[0].set_aspect("equal", adjustable="datalim")
    if zoom:
        x, y, r = zoom
        _tracks(axes[1], tracks, gid=False)
        axes[1].set(xlim=(x - r, x + r), ylim=(y - r, y + r), title=f"zoom: {2 * r:.0f} m around the closest approach",
                    xlabel=x_label)
        axes[1].set_aspect("equal", adjustable="box")
        axes[1].plot([x], [y], "x", color="#b00", ms=8, gid="closest")
        axes[0].add_patch(_square(x, y, r))
    handles, labels = axes[0].get_legend_handles_labels()
    if labels:
        axes[-1].legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return svg(fig, cls)


def _square(x: float, y: float, r: float) -> object:
    from matplotlib.patches import Rectangle

    return Rectangle((x - r, y - r), 2 * r, 2 * r, fill=False, ec="#b00", lw=0.8, ls="--")


def bar_chart(groups: Sequence[str], series: Sequence[str], values: np.ndarray, title: str, y_label: str,
              lo: np.ndarray | None = None, hi: np.ndarray | None = None, cls: str = "bars") -> str:
    """Grouped bars: ``values[g, s]`` for group ``g`` (x axis) and series ``s`` (colour), with
    optional interval whiskers ``lo``/``hi``."""
    fig, (ax,) = figure()
    values = np.asarray(values, float)
    width = 0.8 / max(len(series), 1)
    xs = np.arange(len(groups))
    for k, name in enumerate(series):
        pos = xs - 0.4 + (k + 0.5) * width
        ax.bar(pos, np.nan_to_num(values[:, k]), width, color=f"C{k % 10}", label=name, gid=f"bar:{name}")
        if lo is not None and hi is not None:
            err = np.array([values[:, k] - lo[:, k], hi[:, k] - values[:, k]])
            ax.errorbar(pos, values[:, k], yerr=np.where(np.isfinite(err), err, 0.0), fmt="none", ecolor="#333")
    ax.set_xticks(xs, list(groups))
    ax.set(title=title, ylabel=y_label)
    _legend(ax)
    return svg(fig, cls)


def histogram(data: dict[str, np.ndarray], edges: np.ndarray, title: str, x_label: str) -> str:
    """Counts of runs per bin, one step outline per variant; ticks sit at the bin edges."""
    fig, (ax,) = figure()
    for k, (label, x) in enumerate(data.items()):
        counts, _ = np.histogram(np.clip(x, edges[0], edges[-1]), edges)
        ax.stairs(counts, edges, color=f"C{k % 10}", lw=1.5, label=f"{label} (n={len(x)})", gid=f"bar:{label}")
    step = max(1, math.ceil((len(edges) - 1) / 10))
    ax.set_xticks(edges[::step])
    ax.set(title=title, xlabel=x_label, ylabel="runs")
    _legend(ax)
    return svg(fig, "histogram")


def time_space(t: np.ndarray, pos: np.ndarray, speed: np.ndarray, title: str, vmax: float,
               warmup_s: float = 0.0) -> str:
    """Every vehicle sample as a dot at (time, position along the road) coloured by its speed
    [m/s]: shock waves are red bands running upstream, merges show as new trajectories."""
    fig, (ax,) = figure(TALL)
    pts = ax.scatter(t, pos, c=speed, s=2.0, cmap=SPEED_CMAP, vmin=0.0, vmax=vmax, lw=0, rasterized=True,
                     gid="timespace")
    if warmup_s > 0:
        ax.axvspan(0.0, warmup_s, color="#999", alpha=0.18, lw=0, gid="warmup")
    ax.set(title=title, xlabel="t [s]", ylabel="position along the road [m]")
    fig.colorbar(pts, ax=ax, label="speed [m/s]")
    return svg(fig, "timespace")


def box_or_points(groups: Sequence[tuple[str, np.ndarray]], title: str, x_label: str, min_box: int = 5) -> str:
    """One row per variant: a box plot (with its points) when it has at least ``min_box`` values,
    else the points alone (a box of 1-4 values draws quartiles that are not there)."""
    fig, (ax,) = figure((6.5, 0.9 + 0.45 * len(groups)))
    for i, (label, x) in enumerate(groups, start=1):
        if len(x) >= min_box:
            ax.boxplot([x], positions=[i], vert=False, showmeans=True, widths=0.6)
        jitter = np.linspace(-0.12, 0.12, len(x)) if len(x) > 1 else np.zeros(1)
        ax.plot(x, i + jitter, "o", ms=3 if len(x) >= min_box else 5, alpha=0.6, color="C0", gid=f"points:{label}")
    ax.set_yticks(range(1, len(groups) + 1), [f"{v} (n={len(x)})" for v, x in groups])
    ax.set_ylim(0.4, len(groups) + 0.6)
    ax.set(title=title, xlabel=x_label)
    return svg(fig, "distribution")


def lot_chart(doc: dict, title: str) -> str:
    """A parking lot from above (``parking/lot-<run_id>.json``): outlines, parked cars, the goal bay,
    the planned paths (the last one solid) and the driven path."""
    from matplotlib.patches import Polygon

    fig, (ax,) = figure(TALL)
    style = {"goal_bay": {"fc": "#cfc", "ec": "#070", "lw": 1.2}, "walls": {"fc": "none", "ec": "#333", "lw": 2.0}}
    for name, polys in doc.get("outlines", {}).items():
        for q in polys:
            ax.add_patch(Polygon(np.asarray(q), closed=True, **style.get(name, {"fc": "none", "ec": "#aaa", "lw": 0.6})))
    for q in doc.get("parked", []):
        ax.add_patch(Polygon(np.asarray(q), closed=True, fc="#555", ec="#222", lw=0.5, alpha=0.7))
    plans = doc.get("plans", [])
    for k, p in enumerate(plans):
        xy = np.asarray(p["xy"], float)
        last = k == len(plans) - 1
        ax.plot(xy[:, 0], xy[:, 1], "-" if last else "--", color="C1", lw=1.6 if last else 0.8, alpha=1.0 if last else 0.6,
                label=f"planned ({len(plans)} plan{'s' if len(plans) != 1 else ''})" if last else None,
                gid=f"plan:{k}")
    driven = np.asarray(doc.get("driven", []), float).reshape(-1, 3)
    if len(driven):
        ax.plot(driven[:, 1], driven[:, 2], "-", color="C0", lw=1.4, label="driven", gid="track:driven")
        ax.plot(driven[0, 1], driven[0, 2], "o", color="C0", ms=4)
    if doc.get("goal") is not None:
        gx, gy, gh = doc["goal"]
        ax.annotate("", (gx + 1.5 * np.cos(gh), gy + 1.5 * np.sin(gh)), (gx, gy), arrowprops={"arrowstyle": "->", "color": "#070"})
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(title=title, xlabel="x [m]", ylabel="y [m]")
    _legend(ax)
    return svg(fig, "lot")
