"""Time-series sections of the report, drawn from the runs' recorded signals (``signals/<run_id>.npz``).

A section is a ``SeriesFamily``: the signals whose names start with a prefix (``queue_ccw0``,
``queue_cw3``, ... -> one item per suffix), drawn per variant as lines or as a space x time contour.
A family none of the runs recorded is left out, so any scenario can call ``series_sections``: the
ramp-metering scenario gets the speed contour, ramp queues, meter rates and route split; the others
get nothing (or the families they happen to record).  One representative run per variant: its
first run with ``status == ok`` that kept signals.

``overlay_sections`` draws single signals with all variants in one chart, from one seed that every
variant ran (the same draws and demand: the lines differ only by the variant): minimum
time-to-collision, mean speed and vehicles in the network (road monitors), minimum horizontal and
3-D separation (``uav_separation``).  Long signals are reduced to <= ~300 bins (the bin's minimum for
minima, its mean otherwise).  ``track_sections`` draws top-down x/y paths per variant from signals
``track_e_<id>`` / ``track_n_<id>`` (ENU east / north [m] of entity ``<id>``) when a run recorded them.
``merge_loss_section`` shows the time lost around the merge (``merge_loss_*`` columns) per variant.

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

from corridor.analysis.stats import mean_ci
from corridor.analysis.svgplot import bar_chart, heatmap, line_chart, scatter_chart, track_chart

Series = dict[str, tuple[np.ndarray, np.ndarray]]  # signal name -> (t [s], value)


@dataclass(frozen=True)
class SeriesFamily:
    """Signals ``<prefix><item>`` drawn together, one chart per variant."""

    title: str
    prefix: str
    kind: str  # "lines" or "contour"
    y_label: str  # axis label (lines) or unit (contour)
    note: str = ""


FAMILIES: tuple[SeriesFamily, ...] = (
    SeriesFamily("Mainline speed contour", "speed_down_kmh_", "contour", "km/h",
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
        vmax = max(100.0, float(np.nanmax(grid)) if np.isfinite(grid).any() else 0.0)
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
                       + "".join(f"<div>{c}</div>" for c in charts if c))
    return out


@dataclass(frozen=True)
class Overlay:
    """One signal, one chart, a line per variant."""

    title: str
    signal: str
    y_label: str
    note: str
    reduce: str = "mean"  # per-bin reduction of long signals: "mean" or "min"
    scale: float = 1.0  # unit conversion of the recorded values
    cap: float | None = None  # values above are drawn at the cap


OVERLAYS: tuple[Overlay, ...] = (
    Overlay("Minimum time-to-collision", "min_ttc", "min TTC [s]",
            "Smallest time-to-collision over all leader-follower pairs (bin minimum); values above 10 s "
            "(including no closing pair) are drawn at 10 s.", "min", cap=10.0),
    Overlay("Mean speed", "mean_speed", "mean speed [km/h]", "Mean speed of the vehicles in the network.",
            scale=3.6),
    Overlay("Vehicles in the network", "vehicles", "vehicles [veh]", "Vehicles in the network."),
    Overlay("Minimum horizontal separation", "min_sep_h", "min horizontal separation [m]",
            "Smallest horizontal distance over all aircraft pairs (bin minimum).", "min"),
    Overlay("Minimum 3-D separation", "min_sep_3d", "min 3-D separation [m]",
            "Smallest 3-D distance over all aircraft pairs (bin minimum).", "min"),
)
MAX_BINS = 300
TRACK_E, TRACK_N = "track_e_", "track_n_"


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


def _which(seed: int | None, runs: dict[str, tuple[str, Series]]) -> str:
    ids = "; ".join(f"{html.escape(v)}: <code>{html.escape(rid)}</code>" for v, (rid, _) in runs.items())
    return (f"Seed {seed} of every variant (the same draws), not an average: {ids}." if seed is not None else
            f"One representative run per variant (no seed finished in every variant), not an average: {ids}.")


def overlay_sections(out_dir: Path, df: pd.DataFrame, scenario: Any = None,
                     overlays: tuple[Overlay, ...] = OVERLAYS) -> list[str]:
    """One section per overlay signal that some representative run recorded (>= 2 samples)."""
    seed, runs = common_seed_runs(out_dir, df)
    out = []
    for ov in overlays:
        series = []
        for v, (_, sig) in runs.items():
            if ov.signal in sig and len(sig[ov.signal][0]) >= 2:
                t, x = binned(*sig[ov.signal], how=ov.reduce)
                x = x * ov.scale
                series.append((v, t, np.minimum(x, ov.cap) if ov.cap is not None else x))
        if not series:
            continue
        hlines = overlay_hlines(ov, scenario) if scenario is not None else []
        chart = line_chart(series, ov.title, "t [s]", ov.y_label, hlines)
        out.append(f"<h2>{html.escape(ov.title)}</h2><p>{html.escape(ov.note)} {_which(seed, runs)}</p><div>{chart}</div>")
    return out


def track_sections(out_dir: Path, df: pd.DataFrame) -> list[str]:
    """Top-down paths (``track_e_<id>``, ``track_n_<id>``) of one run per variant, if recorded."""
    seed, runs = common_seed_runs(out_dir, df)
    charts = []
    for v, (_, sig) in runs.items():
        ids = sorted({n[len(TRACK_E):] for n in sig if n.startswith(TRACK_E)} &
                     {n[len(TRACK_N):] for n in sig if n.startswith(TRACK_N)}, key=item_order)
        tracks = []
        for i in ids:
            (te, e), (tn, n) = sig[TRACK_E + i], sig[TRACK_N + i]
            if len(te) >= 2:
                tracks.append((i, e, np.interp(te, tn, n) if len(te) != len(tn) or np.any(te != tn) else n))
        if tracks:
            charts.append(track_chart(tracks, f"{v}: paths seen from above", "east [m]", "north [m]"))
    if not charts:
        return []
    return ["<h2>Trajectories</h2><p>Paths seen from above (local ENU frame, one scale on both axes); "
            f"a circle marks the start, a square the end. {_which(seed, runs)}</p>"
            + "".join(f"<div>{c}</div>" for c in charts)]


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
                      "Time lost around the merge", "mean time lost [s/veh]", stats[..., 1], stats[..., 2])
    runs = ", ".join(f"{html.escape(v)} n={int(n.get(v, 0))}" for v in variants)
    return ("<h2>Time lost around the merge</h2><p>Mean over the ok runs of each variant's merge-area loss "
            "(the part of the delay from 300 m before the acceleration lane to 300 m past its end, as the "
            f"scenario's <code>merge_area</code> sets it), whiskers: 95 % interval over the runs ({runs}).</p>"
            f"<div>{chart}</div>")


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
    out = [scatter_chart(rho, v, [(label, grid, s) for label, s in speeds], "Speed vs density",
                         "density [veh/km/lane]", "speed [km/h]", "fd-speed")]
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
            f"<code>{html.escape(Path(path).name)}</code>: v<sub>free</sub> = {doc['v_free_kmh']:.1f} km/h, "
            f"&rho;<sub>crit</sub> = {doc['rho_crit']:.1f} veh/km/lane, a = {doc['a']:.2f}, capacity "
            f"{doc['capacity_vph_per_lane']:.0f} veh/h/lane, speed RMSE {doc['rmse_kmh']:.1f} km/h, "
            f"{len(doc['points'].get('rho', []))} detector points (one per loop interval, per lane).")
    return (f"<h2>Calibrated fundamental diagram</h2><p>{text}</p>"
            + "".join(f"<div>{c}</div>" for c in diagram_svgs(doc)))


def report_sections(out_dir: Path, df: pd.DataFrame, scenario: Any, scenario_path: Path | str | None) -> list[str]:
    """Everything this module adds to a scenario's report: time-series families, single signals per
    variant, trajectories, the merge-area loss, then the fitted diagram (each only if it has data)."""
    extra = series_sections(out_dir, df, ramp_storage_veh(scenario))
    extra += overlay_sections(out_dir, df, scenario) + track_sections(out_dir, df)
    loss = merge_loss_section(df)
    diagram = diagram_section(calibration_path(scenario_path))
    return extra + [x for x in (loss, diagram) if x]
