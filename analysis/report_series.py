"""Time-series sections of the report, drawn from the runs' recorded signals (``signals/<run_id>.npz``),
with ``corridor.analysis.plots`` (matplotlib, inline SVG).

A section is a ``SeriesFamily``: the signals whose names start with a prefix (``queue_ccw0``,
``queue_cw3``, ... -> one item per suffix), drawn per variant as lines or as a space x time contour.
A family none of the runs recorded is left out, so any scenario can call ``series_sections``: the
ramp-metering scenario gets the speed contour, ramp queues, meter rates and route split; the others
get nothing (or the families they happen to record).  One representative run per variant: its
first run with ``status == ok`` that kept signals.

``overlay_sections`` draws single signals with all variants in one chart: per variant the median
over every ok run in each of ``MAX_BINS`` equal time bins and the interquartile band, the warm-up
shaded: minimum time-to-collision, mean speed and vehicles in the network (road monitors), minimum
horizontal and 3-D separation (``uav_separation``).  Within a bin a run contributes its minimum
(minima) or its mean.  ``time_space_sections`` draws a time-space diagram per variant from the
``time_space`` monitor's ``timespace/ts-<run_id>.npz`` (one seed every variant ran).
``track_sections`` draws top-down x/y paths per variant from signals ``track_e_<id>`` /
``track_n_<id>`` (ENU east / north [m] of entity ``<id>``), a panel zoomed on the closest approach
and the altitude profile (``track_u_<id>``) when a run recorded them.  ``merge_loss_section`` shows
the time lost around the merge (``merge_loss_*`` columns) per variant.

``diagram_section`` draws the fitted fundamental diagram of a calibration file
(``corridor.traffic.macro.calibrate``) against its detector points.
"""

from __future__ import annotations

import html
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from corridor.analysis.plots import (
    band_chart,
    bar_chart,
    heatmap,
    line_chart,
    scatter_chart,
    time_space,
    track_chart,
)
from corridor.analysis.stats import mean_ci

Series = dict[str, tuple[np.ndarray, np.ndarray]]  # signal name -> (t [s], value)
KMH = 3.6  # [km/h per m/s]: detector speeds recorded in km/h are shown in m/s


@dataclass(frozen=True)
class SeriesFamily:
    """Signals ``<prefix><item>`` drawn together, one chart per variant."""

    title: str
    prefix: str
    kind: str  # "lines" or "contour"
    y_label: str  # axis label (lines) or unit (contour)
    note: str = ""


FAMILIES: tuple[SeriesFamily, ...] = (
    SeriesFamily("Mainline speed contour", "speed_down_kmh_", "contour", "speed [m/s]",
                 "Loop speed downstream of each merge, per loop interval; rows are the interchanges in "
                 "order around the ring, per carriageway (ccw outer, cw inner); grey: no vehicle passed."),
    SeriesFamily("Ramp queues", "queue_", "lines", "queue [veh]", "Vehicles queued on each on-ramp."),
    SeriesFamily("Meter rates", "rate_", "lines", "rate [veh/h]",
                 "Metering rate set at each control step (at the open rate: meter off)."),
    SeriesFamily("Route split", "split_ccw_", "lines", "share on the ccw loop",
                 "Route-guidance target: share of the drivers with a choice sent on the outer (ccw) loop."),
)


def item_order(item: str) -> tuple[str, int, str]:
    """Sort key: text prefix, then the number in it (``ccw2`` before ``ccw10``)."""
    m = re.match(r"^(\D*)(\d+)(.*)$", item)
    return (m.group(1), int(m.group(2)), m.group(3)) if m else (item, -1, "")


def load_npz(path: Path) -> Series:
    with np.load(path) as z:
        return {k: (np.asarray(z[f"{k}.t"], float), np.asarray(z[k], float))
                for k in z.files if not k.endswith(".t") and f"{k}.t" in z.files}


def representative_runs(out_dir: Path, df: pd.DataFrame) -> dict[str, tuple[str, Series]]:
    """Per variant (table order): the first ok run with a signals file -> (run_id, its signals)."""
    out: dict[str, tuple[str, Series]] = {}
    if df.empty or "status" not in df:
        return out
    for _, r in df[df["status"] == "ok"].iterrows():
        path = Path(out_dir) / "signals" / f"{r['run_id']}.npz"
        if r["variant"] not in out and path.is_file():
            out[str(r["variant"])] = (str(r["run_id"]), load_npz(path))
    return out


def family_items(sig: Series, prefix: str) -> list[str]:
    return sorted((n[len(prefix):] for n in sig if n.startswith(prefix) and len(sig[n][0])), key=item_order)


def contour_grid(sig: Series, prefix: str, items: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(time edges [s], values[item, interval]): every sample time of any item is a cell's end."""
    times = np.unique(np.concatenate([sig[prefix + i][0] for i in items]))
    step = float(np.median(np.diff(times))) if len(times) > 1 else 60.0
    edges = np.concatenate([[times[0] - step], times])
    grid = np.full((len(items), len(times)), np.nan)
    for r, i in enumerate(items):
        t, v = sig[prefix + i]
        grid[r, np.searchsorted(times, t)] = v
    return edges, grid


def family_chart(fam: SeriesFamily, variant: str, sig: Series, storage_veh: float | None) -> str:
    items = family_items(sig, fam.prefix)
    if not items:
        return ""
    title = f"{variant}: {fam.title.lower()}"
    if fam.kind == "contour":
        edges, grid = contour_grid(sig, fam.prefix, items)
        grid = grid / KMH  # [km/h] recorded -> [m/s] shown (SI throughout the report)
        vmax = max(100.0 / KMH, float(np.nanmax(grid)) if np.isfinite(grid).any() else 0.0)
        return heatmap(items, edges, grid, title, "t [s]", fam.y_label, vmax)
    series = [(i, *sig[fam.prefix + i]) for i in items]
    dashed = [i.startswith("cw") for i in items] if any(i.startswith("ccw") for i in items) else None
    hlines = [(storage_veh, f"storage {storage_veh:g} veh")] if fam.prefix == "queue_" and storage_veh else []
    return line_chart(series, title, "t [s]", fam.y_label, hlines, dashed=dashed)


def series_sections(out_dir: Path, df: pd.DataFrame, storage_veh: float | None = None,
                    families: tuple[SeriesFamily, ...] = FAMILIES) -> list[str]:
    """HTML sections (``<h2>`` + note + one chart per variant) for every family some run recorded."""
    runs = representative_runs(out_dir, df)
    if not runs:
        return []
    which = "; ".join(f"{html.escape(v)}: <code>{html.escape(rid)}</code>" for v, (rid, _) in runs.items())
    out = []
    for fam in families:
        charts = [family_chart(fam, v, sig, storage_veh) for v, (_, sig) in runs.items()]
        if any(charts):
            out.append(f"<h2>{html.escape(fam.title)}</h2><p>{html.escape(fam.note)} One representative run "
                       f"per variant (the first seed that finished), not an average: {which}.</p>"
                       + "".join(c for c in charts if c))
    return out


@dataclass(frozen=True)
class Overlay:
    """One signal, one chart: per variant the median over its runs and the interquartile band."""

    title: str
    signal: str
    y_label: str
    note: str
    reduce: str = "mean"  # per-bin reduction of long signals: "mean" or "min"
    scale: float = 1.0  # unit conversion of the recorded values
    cap: float | None = None  # values above are drawn at the cap
    missing: float | None = None  # a NaN sample stands for this value (no closing pair: TTC = inf)


OVERLAYS: tuple[Overlay, ...] = (
    Overlay("Minimum time-to-collision", "min_ttc", "min TTC [s]",
            "Smallest time-to-collision over all leader-follower pairs (bin minimum); values above 10 s "
            "and instants without a closing pair are drawn at 10 s.", "min", cap=10.0, missing=np.inf),
    Overlay("Mean speed", "mean_speed", "mean speed [m/s]", "Mean speed of the vehicles in the network."),
    Overlay("Vehicles in the network", "vehicles", "vehicles [veh]", "Vehicles in the network."),
    Overlay("Minimum horizontal separation", "min_sep_h", "min horizontal separation [m]",
            "Smallest horizontal distance over all aircraft pairs (bin minimum).", "min"),
    Overlay("Minimum 3-D separation", "min_sep_3d", "min 3-D separation [m]",
            "Smallest 3-D distance over all aircraft pairs (bin minimum).", "min"),
)
MAX_BINS = 300
MAX_RUNS = 200  # runs per variant read for the median and band (the first seeds)
TRACK_E, TRACK_N, TRACK_U = "track_e_", "track_n_", "track_u_"


def binned(t: np.ndarray, v: np.ndarray, how: str = "mean", max_bins: int = MAX_BINS) -> tuple[np.ndarray, np.ndarray]:
    """A signal reduced to at most ``max_bins`` equal time bins (bin centre, bin mean or minimum);
    shorter signals are returned as they are."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    if len(t) <= max_bins:
        return t, v
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    edges = np.linspace(t[0], t[-1], max_bins + 1)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, max_bins - 1)
    starts = np.flatnonzero(np.r_[True, np.diff(idx) > 0])
    red = np.minimum.reduceat(v, starts) if how == "min" else np.add.reduceat(v, starts) / np.diff(np.r_[starts, len(v)])
    return (edges[idx[starts]] + edges[idx[starts] + 1]) / 2, red


def on_grid(t: np.ndarray, v: np.ndarray, edges: np.ndarray, how: str = "mean") -> np.ndarray:
    """A signal's bin values on fixed time ``edges`` (mean or minimum of the samples in each bin;
    NaN where a bin has none), so that runs can be compared bin by bin."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    ok = np.isfinite(t) & ~np.isnan(v)
    t, v = t[ok], v[ok]
    out = np.full(len(edges) - 1, np.nan)
    idx = np.searchsorted(edges, t, side="right") - 1
    idx[t == edges[-1]] = len(edges) - 2
    keep = (idx >= 0) & (idx < len(out))
    idx, v = idx[keep], v[keep]
    if not len(idx):
        return out
    if how == "min":
        red = np.full(len(out), np.inf)
        np.minimum.at(red, idx, v)
    else:
        red = np.bincount(idx, v, minlength=len(out)) / np.maximum(np.bincount(idx, minlength=len(out)), 1)
    has = np.bincount(idx, minlength=len(out)) > 0
    out[has] = red[has]
    return out


def variant_runs(out_dir: Path, df: pd.DataFrame, max_runs: int = MAX_RUNS) -> dict[str, list[Path]]:
    """Per variant (table order): the signal files of its ok runs (lowest seeds first)."""
    if df.empty or "status" not in df:
        return {}
    ok = df[df["status"] == "ok"]
    ok = ok.sort_values("seed", kind="stable") if "seed" in ok else ok
    out: dict[str, list[Path]] = {}
    for v in dict.fromkeys(df["variant"].astype(str)):
        paths = [Path(out_dir) / "signals" / f"{r}.npz" for r in ok[ok["variant"].astype(str) == v]["run_id"]]
        if paths := [p for p in paths if p.is_file()][:max_runs]:
            out[v] = paths
    return out


def quartile_series(ov: Overlay, files: list[Path], edges: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """(median, q25, q75, runs) of one overlay signal over the runs' files, per time bin."""
    rows = []
    for path in files:
        sig = load_npz(path)
        if ov.signal not in sig or len(sig[ov.signal][0]) < 2:
            continue
        t, v = sig[ov.signal]
        v = np.where(np.isnan(v), ov.missing, v) if ov.missing is not None else v
        v = v * ov.scale
        rows.append(on_grid(t, np.minimum(v, ov.cap) if ov.cap is not None else v, edges, ov.reduce))
    if not rows:
        return None
    grid = np.array(rows)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a bin no run has a sample in: NaN
            q = np.nanpercentile(grid, [50, 25, 75], axis=0)
    return q[0], q[1], q[2], np.array(len(rows))


def _duration(scenario: Any, runs: dict[str, list[Path]]) -> float:
    if scenario is not None and getattr(scenario, "duration", None):
        return float(scenario.duration)
    ends = [float(np.max(t)) for files in runs.values() for path in files[:1]
            for t, _ in load_npz(path).values() if len(t)]
    return max(ends, default=1.0)


def _monitor_params(scenario: Any, monitor_type: str) -> Any:
    """The validated ``Params`` of the scenario's first monitor of this type (None if it has none)."""
    from corridor.registry import MONITORS

    for spec in getattr(scenario, "monitors", {}).values():
        if spec.type == monitor_type:
            model = getattr(MONITORS.get(spec.type), "Params", None)
            return model.model_validate(spec.params) if model is not None else None
    return None


def overlay_hlines(ov: Overlay, scenario: Any) -> list[tuple[float, str]]:
    """Reference lines of an overlay chart, from the scenario's monitor thresholds."""
    if ov.signal == "min_ttc" and (p := _monitor_params(scenario, "surrogate_safety")) is not None:
        return [(p.ttc_threshold_s, f"TTC threshold {p.ttc_threshold_s:g} s")]
    if ov.signal == "min_sep_h" and (p := _monitor_params(scenario, "uav_separation")) is not None:
        return [(p.nmac_h_m, f"NMAC {p.nmac_h_m:.1f} m"), (p.los_h_m, f"LoS (UAV-UAV) {p.los_h_m:.1f} m")]
    return []


def overlay_sections(out_dir: Path, df: pd.DataFrame, scenario: Any = None,
                     overlays: tuple[Overlay, ...] = OVERLAYS) -> list[str]:
    """One section per overlay signal that some run recorded (>= 2 samples): per variant the median
    over its ok runs and the interquartile band, on MAX_BINS equal time bins; warm-up shaded."""
    runs = variant_runs(out_dir, df)
    if not runs:
        return []
    edges = np.linspace(0.0, _duration(scenario, runs), MAX_BINS + 1)
    centres = (edges[:-1] + edges[1:]) / 2
    warmup = float(getattr(scenario, "warmup", 0.0) or 0.0)
    out = []
    for ov in overlays:
        series = [(v, centres, *q[:3], int(q[3])) for v, files in runs.items()
                  if (q := quartile_series(ov, files, edges)) is not None]
        if not series:
            continue
        hlines = overlay_hlines(ov, scenario) if scenario is not None else []
        chart = band_chart(series, ov.title, "t [s]", ov.y_label, warmup, hlines)
        n = ", ".join(f"{html.escape(v)} n={k}" for v, *_, k in series)
        out.append(f"<h2>{html.escape(ov.title)}</h2><p>{html.escape(ov.note)} Line: the median over the "
                   f"variant's runs in each of {MAX_BINS} time bins; band: their interquartile range ({n}); "
                   f"grey: the warm-up, not measured.</p>{chart}")
    return out


def common_seed_runs(out_dir: Path, df: pd.DataFrame) -> tuple[int | None, dict[str, tuple[str, Series]]]:
    """(seed, variant -> (run_id, signals)) for the first seed at which every variant that has an ok
    run with signals has one; else (None, each variant's first such run)."""
    first = representative_runs(out_dir, df)
    if not first or "seed" not in df:
        return None, first
    ok = df[(df["status"] == "ok") & df["variant"].astype(str).isin(first)]
    for seed, g in ok.groupby("seed", sort=True):
        paths = {str(r["variant"]): (str(r["run_id"]), Path(out_dir) / "signals" / f"{r['run_id']}.npz")
                 for _, r in g.iterrows()}
        if set(paths) == set(first) and all(p.is_file() for _, p in paths.values()):
            return int(seed), {v: (rid, first[v][1] if first[v][0] == rid else load_npz(p))
                               for v, (rid, p) in sorted(paths.items(), key=lambda kv: list(first).index(kv[0]))}
    return None, first


def _which(seed: int | None, runs: dict[str, tuple[str, Series]]) -> str:
    ids = "; ".join(f"{html.escape(v)}: <code>{html.escape(rid)}</code>" for v, (rid, _) in runs.items())
    return (f"Seed {seed} of every variant (the same draws), not an average: {ids}." if seed is not None else
            f"One representative run per variant (no seed finished in every variant), not an average: {ids}.")


def _tracks_of(sig: Series) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]:
    """(id, t, east, north, up or None) of every entity whose track a run recorded."""
    ids = sorted({n[len(TRACK_E):] for n in sig if n.startswith(TRACK_E)} &
                 {n[len(TRACK_N):] for n in sig if n.startswith(TRACK_N)}, key=item_order)
    out = []
    for i in ids:
        (te, e), (tn, n) = sig[TRACK_E + i], sig[TRACK_N + i]
        if len(te) < 2:
            continue
        n = np.interp(te, tn, n) if len(te) != len(tn) or np.any(te != tn) else n
        u = np.interp(te, *sig[TRACK_U + i]) if TRACK_U + i in sig and len(sig[TRACK_U + i][0]) else None
        out.append((i, te, e, n, u))
    return out


def closest_approach(tracks: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]
                     ) -> tuple[float, float, float] | None:
    """(east, north, distance [m]) of the closest horizontal approach of two tracks (at common
    sample times), the middle of the pair; None with fewer than two tracks."""
    best: tuple[float, float, float] | None = None
    for a in range(len(tracks)):
        for b in range(a + 1, len(tracks)):
            (_, ta, ea, na, _), (_, tb, eb, nb, _) = tracks[a], tracks[b]
            t = np.intersect1d(ta, tb)
            if not len(t):
                continue
            pa = np.column_stack([np.interp(t, ta, ea), np.interp(t, ta, na)])
            pb = np.column_stack([np.interp(t, tb, eb), np.interp(t, tb, nb)])
            d = np.hypot(*(pa - pb).T)
            k = int(np.nanargmin(d))
            if best is None or d[k] < best[2]:
                mid = (pa[k] + pb[k]) / 2
                best = (float(mid[0]), float(mid[1]), float(d[k]))
    return best


ZOOM_MIN_HALF_M = 100.0  # [m] half-width of the encounter panel at least


def track_sections(out_dir: Path, df: pd.DataFrame) -> list[str]:
    """Top-down paths (``track_e_<id>``, ``track_n_<id>``) of one run per variant, with a second panel
    zoomed on the closest approach, and the altitude profile (``track_u_<id>``) when recorded."""
    seed, runs = common_seed_runs(out_dir, df)
    charts = []
    for v, (_, sig) in runs.items():
        tracks = _tracks_of(sig)
        if not tracks:
            continue
        ca = closest_approach(tracks)
        zoom = (ca[0], ca[1], max(ZOOM_MIN_HALF_M, 3.0 * ca[2])) if ca is not None else None
        title = f"{v}: paths seen from above" + (f" (closest approach {ca[2]:.1f} m)" if ca else "")
        charts.append(track_chart([(i, e, n) for i, _, e, n, _ in tracks], title, "east [m]", "north [m]", zoom=zoom))
        alt = [(i, t, u) for i, t, _, _, u in tracks if u is not None]
        if alt:
            charts.append(line_chart(alt, f"{v}: altitude profile", "t [s]", "altitude above the origin [m]",
                                     cls="altitude"))
    if not charts:
        return []
    return ["<h2>Trajectories</h2><p>Paths seen from above (local ENU frame, one scale on both axes); "
            "a circle marks the start, a square the end; the right panel zooms on the closest approach of "
            f"two tracks (red cross), the chart below is the altitude over time. {_which(seed, runs)}</p>"
            + "".join(charts)]


def load_time_space(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: np.asarray(z[k]) for k in z.files}


def time_space_sections(out_dir: Path, df: pd.DataFrame, scenario: Any = None) -> list[str]:
    """A time-space diagram per variant (``timespace/ts-<run_id>.npz`` of the ``time_space``
    monitor), for one seed every variant ran: each vehicle sample at (t, position) coloured by speed."""
    ok = df[df["status"] == "ok"] if "status" in df else df
    if ok.empty or not (Path(out_dir) / "timespace").is_dir():
        return []
    files = {str(r["run_id"]): Path(out_dir) / "timespace" / f"ts-{r['run_id']}.npz" for _, r in ok.iterrows()}
    ok = ok[[files[str(r)].is_file() for r in ok["run_id"]]]
    if ok.empty:
        return []
    variants = list(dict.fromkeys(ok["variant"].astype(str)))
    seeds = [s for s, g in ok.groupby("seed", sort=True) if set(g["variant"].astype(str)) == set(variants)] \
        if "seed" in ok else []
    pick = ok[ok["seed"] == seeds[0]] if seeds else ok.drop_duplicates("variant")
    warmup = float(getattr(scenario, "warmup", 0.0) or 0.0)
    data = {str(r["variant"]): (str(r["run_id"]), load_time_space(files[str(r["run_id"])])) for _, r in pick.iterrows()}
    vmax = max([float(np.nanmax(d["speed"])) for _, d in data.values() if len(d["speed"])], default=1.0)
    charts = [time_space(d["t"], d["x"], d["speed"], f"{v}: time-space diagram ({rid})", vmax, warmup)
              for v, (rid, d) in data.items() if len(d["t"])]
    if not charts:
        return []
    which = f"seed {seeds[0]} of every variant (the same demand)" if seeds else "one run per variant"
    return ["<h2>Time-space diagram</h2><p>Every vehicle on the road at each sample (the "
            "<code>time_space</code> monitor) at its time and position along the road (east coordinate), "
            "coloured by speed [m/s]: a red band running backwards in time is a shock wave, a merge shows as "
            f"a trajectory joining; grey: the warm-up. From {which}, not an average.</p>" + "".join(charts)]


MERGE_LOSS = (("merge_loss_ramp_s", "ramp vehicles"), ("merge_loss_mainline_s", "mainline vehicles"),
              ("merge_loss_mean_s", "all vehicles"))


def merge_loss_section(df: pd.DataFrame) -> str:
    """Mean time lost around the merge per variant (ramp, mainline, all) with 95 % intervals."""
    cols = [(c, label) for c, label in MERGE_LOSS if c in df]
    ok = df[df["status"] == "ok"] if "status" in df else df
    if not cols or ok.empty:
        return ""
    variants = list(dict.fromkeys(ok["variant"].astype(str)))
    stats = np.array([[mean_ci(pd.to_numeric(ok[ok["variant"].astype(str) == v][c], errors="coerce")
                               .to_numpy(dtype=float)) for c, _ in cols] for v in variants])  # [variant, col, 3]
    if not np.isfinite(stats[..., 0]).any():
        return ""
    n = ok.groupby(ok["variant"].astype(str)).size()
    chart = bar_chart(variants, [label for _, label in cols], stats[..., 0],
                      "Time lost around the merge", "mean time lost [s]", stats[..., 1], stats[..., 2])
    runs = ", ".join(f"{html.escape(v)} n={int(n.get(v, 0))}" for v in variants)
    return ("<h2>Time lost around the merge</h2><p>Mean over the ok runs of each variant's merge-area loss "
            "(the part of the delay from 300 m before the acceleration lane to 300 m past its end, as the "
            f"scenario's <code>merge_area</code> sets it), whiskers: 95 % interval over the runs ({runs}).</p>"
            f"{chart}")


def ramp_storage_veh(scenario: Any) -> float | None:
    """On-ramp storage [veh] of a beltway scenario (as the network builder computes it), else None."""
    from corridor.traffic.sumo.road_spec import road_spec

    road = road_spec(scenario)
    if road is None or road.network.type != "beltway":
        return None
    from corridor.traffic.networks.beltway import VEHICLE_SPACING_M

    return float(int(road.network.params.ramp_length_m // VEHICLE_SPACING_M))


def calibration_path(scenario_path: Path | str | None) -> Path | None:
    """``<scenario>.calibration.json`` beside the scenario file (where ``calibrate`` writes it), if any."""
    if scenario_path is None:
        return None
    p = Path(scenario_path).with_suffix("").with_suffix(".calibration.json")
    return p if p.is_file() else None


def diagram_svgs(doc: dict[str, Any]) -> list[str]:
    """Speed-density and (when flows were stored) flow-density charts of a calibration document."""
    from corridor.traffic.macro.calibrate import FdFit

    pts = doc.get("points", {})
    rho, v = np.asarray(pts.get("rho", []), float), np.asarray(pts.get("v_kmh", []), float)
    grid = np.linspace(0.0, max(float(np.nanmax(rho)) if len(rho) else 0.0, 2.5 * doc["rho_crit"]), 200)
    fits = [("fit (all loops)", doc)]
    if "downstream_fit" in doc:
        fits.append(("fit (downstream loops)", doc["downstream_fit"]))
    speeds = [(label, FdFit(f["v_free_kmh"], f["rho_crit"], f["a"], 0.0, 0.0, 0).speed(grid)) for label, f in fits]
    out = [scatter_chart(rho, v / KMH, [(label, grid, s / KMH) for label, s in speeds], "Speed vs density",
                         "density [veh/km/lane]", "speed [m/s]", "fd-speed")]
    if "q" in pts:
        out.append(scatter_chart(rho, np.asarray(pts["q"], float), [(label, grid, grid * s) for label, s in speeds],
                                 "Flow vs density", "density [veh/km/lane]", "flow [veh/h/lane]", "fd-flow"))
    return out


def diagram_section(path: Path | None) -> str:
    """The fitted fundamental diagram against the detector points of a calibration JSON ("" if none)."""
    if path is None or not Path(path).is_file():
        return ""
    doc = json.loads(Path(path).read_text())
    if "points" not in doc:
        return ""
    text = (f"Fit of V(&rho;) = v<sub>free</sub> exp(-(1/a)(&rho;/&rho;<sub>crit</sub>)<sup>a</sup>) from "
            f"<code>{html.escape(Path(path).name)}</code>: v<sub>free</sub> = {doc['v_free_kmh'] / KMH:.1f} m/s, "
            f"&rho;<sub>crit</sub> = {doc['rho_crit']:.1f} veh/km/lane, a = {doc['a']:.2f}, capacity "
            f"{doc['capacity_vph_per_lane']:.0f} veh/h/lane, speed RMSE {doc['rmse_kmh'] / KMH:.2f} m/s, "
            f"{len(doc['points'].get('rho', []))} detector points (one per loop interval, per lane).")
    return (f"<h2>Calibrated fundamental diagram</h2><p>{text}</p>"
            + "".join(diagram_svgs(doc)))


def report_sections(out_dir: Path, df: pd.DataFrame, scenario: Any, scenario_path: Path | str | None) -> list[str]:
    """Everything this module adds to a scenario's report: time-series families, single signals per
    variant, trajectories, the merge-area loss, then the fitted diagram (each only if it has data)."""
    extra = series_sections(out_dir, df, ramp_storage_veh(scenario))
    extra += overlay_sections(out_dir, df, scenario) + time_space_sections(out_dir, df, scenario)
    extra += track_sections(out_dir, df)
    loss = merge_loss_section(df)
    diagram = diagram_section(calibration_path(scenario_path))
    return extra + [x for x in (loss, diagram) if x]
