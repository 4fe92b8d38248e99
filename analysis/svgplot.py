"""Small hand-written inline SVG charts for the HTML report: line charts, a heatmap, a scatter plot,
a top-down x/y track chart (equal scale on both axes) and a grouped bar chart.

No plotting library: the report stays a few hundred kB of text, and tests can count the drawn
elements (``<polyline>`` per series or track, ``<rect class=cell>`` per heatmap cell, ``<circle>``
per point, ``<rect class=bar>`` per bar).
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf")
W, H = 640, 260  # [px] chart size
ML, MR, MT, MB = 56, 120, 26, 38  # [px] margins: left (y ticks), right (legend), top (title), bottom


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About ``n`` round tick values (1, 2, 2.5, 5 x 10^k steps) covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + i * step, 10) for i in range(int((hi - first) / step + 1e-9) + 1)]


def _fmt(x: float) -> str:
    return f"{x:g}" if abs(x) < 1e5 else f"{x:.3g}"


@dataclass(frozen=True)
class Frame:
    """The plot area of one chart and its data ranges (x to the right, y upwards)."""

    x0: float
    x1: float
    y0: float
    y1: float

    def px(self, x: np.ndarray | float) -> np.ndarray:
        return ML + (np.asarray(x, float) - self.x0) / ((self.x1 - self.x0) or 1.0) * (W - ML - MR)

    def py(self, y: np.ndarray | float) -> np.ndarray:
        return H - MB - (np.asarray(y, float) - self.y0) / ((self.y1 - self.y0) or 1.0) * (H - MT - MB)


def _axes(f: Frame, title: str, x_label: str, y_label: str, y_ticks: bool = True) -> list[str]:
    out = [f'<rect x="{ML}" y="{MT}" width="{W - ML - MR}" height="{H - MT - MB}" fill="none" stroke="#999"/>',
           f'<text x="{ML}" y="{MT - 8}" font-size="13" font-weight="bold">{html.escape(title)}</text>',
           f'<text x="{(W - MR + ML) / 2:.0f}" y="{H - 4}" font-size="11" text-anchor="middle">'
           f"{html.escape(x_label)}</text>",
           f'<text x="12" y="{(H - MB + MT) / 2:.0f}" font-size="11" text-anchor="middle" '
           f'transform="rotate(-90 12 {(H - MB + MT) / 2:.0f})">{html.escape(y_label)}</text>']
    for x in nice_ticks(f.x0, f.x1):
        px = float(f.px(x))
        out.append(f'<line x1="{px:.1f}" x2="{px:.1f}" y1="{H - MB}" y2="{H - MB + 4}" stroke="#999"/>'
                   f'<text x="{px:.1f}" y="{H - MB + 15}" font-size="10" text-anchor="middle">{_fmt(x)}</text>')
    for y in nice_ticks(f.y0, f.y1) if y_ticks else []:
        py = float(f.py(y))
        out.append(f'<line x1="{ML}" x2="{W - MR}" y1="{py:.1f}" y2="{py:.1f}" stroke="#eee"/>'
                   f'<text x="{ML - 4}" y="{py + 3:.1f}" font-size="10" text-anchor="end">{_fmt(y)}</text>')
    return out


def _svg(parts: list[str], cls: str) -> str:
    return (f'<svg class="{cls}" xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" '
            f'viewBox="0 0 {W} {H}" font-family="sans-serif">{"".join(parts)}</svg>')


def _polyline(f: Frame, x: np.ndarray, y: np.ndarray, colour: str, dash: bool = False) -> str:
    ok = np.isfinite(x) & np.isfinite(y)
    pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(f.px(x[ok]), f.py(y[ok])))
    style = ' stroke-dasharray="5 3"' if dash else ""
    return f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="1.4"{style}/>'


def _legend(labels: Sequence[tuple[str, str, bool]]) -> list[str]:
    out, step = [], min(14.0, (H - MT - MB) / max(len(labels), 1))
    for i, (label, colour, dash) in enumerate(labels):
        y = MT + 6 + i * step
        style = ' stroke-dasharray="5 3"' if dash else ""
        out.append(f'<line x1="{W - MR + 8}" x2="{W - MR + 26}" y1="{y:.1f}" y2="{y:.1f}" stroke="{colour}" '
                   f'stroke-width="2"{style}/><text x="{W - MR + 30}" y="{y + 3:.1f}" font-size="10">'
                   f"{html.escape(label)}</text>")
    return out


def _range(arrays: Sequence[np.ndarray], lo: float | None = None) -> tuple[float, float]:
    vals = np.concatenate([np.asarray(a, float).ravel() for a in arrays]) if arrays else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    a = float(vals.min()) if len(vals) else 0.0
    b = float(vals.max()) if len(vals) else 1.0
    a = a if lo is None else min(lo, a)
    return (a, b) if b > a else (a, a + 1.0)


def line_chart(series: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str, x_label: str, y_label: str,
               hlines: Sequence[tuple[float, str]] = (), y_min: float | None = 0.0,
               dashed: Sequence[bool] | None = None) -> str:
    """One polyline per (label, t, v) series, plus labelled horizontal reference lines."""
    x0, x1 = _range([s[1] for s in series])
    y0, y1 = _range([s[2] for s in series] + [np.array([h for h, _ in hlines])], y_min)
    f = Frame(x0, x1, y0, y1 * 1.04)
    parts = _axes(f, title, x_label, y_label)
    legend = []
    for i, (label, t, v) in enumerate(series):
        colour, dash = PALETTE[i % len(PALETTE)], bool(dashed[i]) if dashed else i >= len(PALETTE)
        parts.append(_polyline(f, np.asarray(t, float), np.asarray(v, float), colour, dash))
        legend.append((label, colour, dash))
    for y, label in hlines:
        py = float(f.py(y))
        parts.append(f'<line class="ref" x1="{ML}" x2="{W - MR}" y1="{py:.1f}" y2="{py:.1f}" stroke="#b00" '
                     f'stroke-dasharray="2 2"/><text x="{ML + 4}" y="{py - 3:.1f}" font-size="10" fill="#b00">'
                     f"{html.escape(label)}</text>")
    return _svg(parts + _legend(legend), "lines")


def speed_colour(v: float, vmax: float) -> str:
    """Red (stopped) -> yellow (half of ``vmax``) -> green (``vmax``); grey when unknown."""
    if not math.isfinite(v):
        return "#ddd"
    s = min(max(v / vmax, 0.0), 1.0)
    r, g = (220, int(40 + 400 * s)) if s < 0.5 else (int(220 - 400 * (s - 0.5)), 200)
    return f"#{min(r, 255):02x}{min(g, 255):02x}30"


def heatmap(rows: Sequence[str], t_edges: np.ndarray, values: np.ndarray, title: str, x_label: str,
            unit: str, vmax: float) -> str:
    """A rows x time grid of coloured cells (``values[i, j]`` spans ``t_edges[j]..t_edges[j+1]``)."""
    f = Frame(float(t_edges[0]), float(t_edges[-1]), 0.0, float(len(rows)))
    parts = _axes(f, title, x_label, "", y_ticks=False)
    xs = f.px(t_edges)
    row_h = (H - MT - MB) / max(len(rows), 1)
    for i, name in enumerate(rows):
        y = MT + i * row_h
        parts.append(f'<text x="{ML - 4}" y="{y + row_h / 2 + 3:.1f}" font-size="9" text-anchor="end">'
                     f"{html.escape(name)}</text>")
        for j in range(values.shape[1]):
            val = float(values[i, j])
            parts.append(f'<rect class="cell" x="{xs[j]:.1f}" y="{y:.1f}" width="{max(xs[j + 1] - xs[j], 0.5):.1f}" '
                         f'height="{row_h:.1f}" fill="{speed_colour(val, vmax)}"><title>{html.escape(name)} '
                         f"t={t_edges[j]:g}: {_fmt(round(val, 1))} {html.escape(unit)}</title></rect>")
    for k, v in enumerate(np.linspace(0, vmax, 5)):
        y = MT + 6 + k * 14
        parts.append(f'<rect x="{W - MR + 8}" y="{y - 5}" width="14" height="10" fill="{speed_colour(v, vmax)}"/>'
                     f'<text x="{W - MR + 26}" y="{y + 4}" font-size="10">{v:.0f} {html.escape(unit)}</text>')
    return _svg(parts, "heatmap")


def scatter_chart(x: np.ndarray, y: np.ndarray, curves: Sequence[tuple[str, np.ndarray, np.ndarray]],
                  title: str, x_label: str, y_label: str, cls: str) -> str:
    """Points (one ``<circle>`` each) with model curves drawn over them."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    f = Frame(*_range([x[ok], *(c[1] for c in curves)], 0.0), *_range([y[ok], *(c[2] for c in curves)], 0.0))
    parts = _axes(f, title, x_label, y_label)
    parts += [f'<circle cx="{a:.1f}" cy="{b:.1f}" r="1.8" fill="#1f77b4" fill-opacity="0.35"/>'
              for a, b in zip(f.px(x[ok]), f.py(y[ok]))]
    legend = [("detector points", "#1f77b4", False)]
    for i, (label, cx, cy) in enumerate(curves):
        colour = ("#d62728", "#2ca02c", "#9467bd")[i % 3]
        parts.append(_polyline(f, np.asarray(cx, float), np.asarray(cy, float), colour, dash=i > 0))
        legend.append((label, colour, i > 0))
    return _svg(parts + _legend(legend), cls)


def track_chart(tracks: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str, x_label: str, y_label: str,
                cls: str = "tracks") -> str:
    """Top-down paths, one ``<polyline>`` per (label, x, y) track, at one scale on both axes (a
    circle marks where a track starts, a square where it ends)."""
    x0, x1 = _range([t[1] for t in tracks])
    y0, y1 = _range([t[2] for t in tracks])
    pw, ph = W - ML - MR, H - MT - MB
    scale = max((x1 - x0) / pw, (y1 - y0) / ph)  # [m/px]: the larger extent fills its axis
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    f = Frame(cx - scale * pw / 2, cx + scale * pw / 2, cy - scale * ph / 2, cy + scale * ph / 2)
    parts = _axes(f, title, x_label, y_label)
    legend = []
    for i, (label, x, y) in enumerate(tracks):
        colour, dash = PALETTE[i % len(PALETTE)], i >= len(PALETTE)
        x, y = np.asarray(x, float), np.asarray(y, float)
        parts.append(_polyline(f, x, y, colour, dash))
        ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        if len(ok):
            (a, b), (c, d) = (f.px(x[ok[[0, -1]]]), f.py(y[ok[[0, -1]]]))
            parts.append(f'<circle cx="{a:.1f}" cy="{c:.1f}" r="3" fill="{colour}"/>'
                         f'<rect x="{b - 3:.1f}" y="{d - 3:.1f}" width="6" height="6" fill="{colour}"/>')
        legend.append((label, colour, dash))
    return _svg(parts + _legend(legend), cls)


def bar_chart(groups: Sequence[str], series: Sequence[str], values: np.ndarray, title: str, y_label: str,
              lo: np.ndarray | None = None, hi: np.ndarray | None = None, cls: str = "bars") -> str:
    """Grouped bars: ``values[g, s]`` for group ``g`` (x axis) and series ``s`` (colour, legend), with
    optional interval whiskers ``lo``/``hi`` of the same shape."""
    values = np.asarray(values, float)
    ends = [values] + [np.asarray(a, float) for a in (lo, hi) if a is not None]
    y0, y1 = _range(ends, 0.0)
    f = Frame(0.0, float(len(groups)), y0, y1 * 1.08)
    parts = _axes(f, title, "", y_label)[:4]  # frame, title, labels: no numeric x ticks
    parts += [f'<line x1="{ML}" x2="{W - MR}" y1="{float(f.py(y)):.1f}" y2="{float(f.py(y)):.1f}" stroke="#eee"/>'
              f'<text x="{ML - 4}" y="{float(f.py(y)) + 3:.1f}" font-size="10" text-anchor="end">{_fmt(y)}</text>'
              for y in nice_ticks(f.y0, f.y1)]
    n = max(len(series), 1)
    width = 0.8 / n
    for g, name in enumerate(groups):
        parts.append(f'<text x="{float(f.px(g + 0.5)):.1f}" y="{H - MB + 15}" font-size="10" '
                     f'text-anchor="middle">{html.escape(name)}</text>')
        for k in range(len(series)):
            v = values[g, k]
            if not math.isfinite(v):
                continue
            xa, xb = float(f.px(g + 0.1 + k * width)), float(f.px(g + 0.1 + (k + 1) * width))
            ya, yb = sorted((float(f.py(v)), float(f.py(0.0))))
            parts.append(f'<rect class="bar" x="{xa:.1f}" y="{ya:.1f}" width="{xb - xa:.1f}" height="{yb - ya:.1f}" '
                         f'fill="{PALETTE[k % len(PALETTE)]}"><title>{html.escape(name)}, '
                         f"{html.escape(series[k])}: {_fmt(round(float(v), 3))}</title></rect>")
            if lo is not None and hi is not None and math.isfinite(lo[g, k]) and math.isfinite(hi[g, k]):
                xm = (xa + xb) / 2
                parts.append(f'<line x1="{xm:.1f}" x2="{xm:.1f}" y1="{float(f.py(lo[g, k])):.1f}" '
                             f'y2="{float(f.py(hi[g, k])):.1f}" stroke="#333"/>')
    return _svg(parts + _legend([(s_, PALETTE[k % len(PALETTE)], False) for k, s_ in enumerate(series)]), cls)
