"""Time-series sections of the report, drawn from the runs' recorded signals (``signals/<run_id>.npz``).

A section is a ``SeriesFamily``: the signals whose names start with a prefix (``queue_ccw0``,
``queue_cw3``, ... -> one item per suffix), drawn per variant as lines or as a space x time contour.
A family none of the runs recorded is left out, so any scenario can call ``series_sections``: the
ramp-metering scenario gets the speed contour, ramp queues, meter rates and route split; the others
get nothing (or the families they happen to record).  One representative run per variant: its
first run with ``status == ok`` that kept signals.

``diagram_section`` draws the fitted fundamental diagram of a calibration file
(``corridor.traffic.calibrate``) against its detector points.
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

from corridor.analysis.svgplot import heatmap, line_chart, scatter_chart

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


def ramp_storage_veh(scenario: Any) -> float | None:
    """On-ramp storage [veh] of a beltway scenario (as the network builder computes it), else None."""
    road = getattr(scenario, "road", None)
    if road is None or road.network.type != "beltway":
        return None
    from corridor.traffic.net_beltway import VEHICLE_SPACING_M, BeltwayParams

    return float(int(BeltwayParams.model_validate(road.network.params).ramp_length_m // VEHICLE_SPACING_M))


def calibration_path(scenario_path: Path | str | None) -> Path | None:
    """``<scenario>.calibration.json`` beside the scenario file (where ``calibrate`` writes it), if any."""
    if scenario_path is None:
        return None
    p = Path(scenario_path).with_suffix("").with_suffix(".calibration.json")
    return p if p.is_file() else None


def diagram_svgs(doc: dict[str, Any]) -> list[str]:
    """Speed-density and (when flows were stored) flow-density charts of a calibration document."""
    from corridor.traffic.calibrate import FdFit

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
    """Everything this module adds to a scenario's report: time series, then the fitted diagram."""
    extra = series_sections(out_dir, df, ramp_storage_veh(scenario))
    diagram = diagram_section(calibration_path(scenario_path))
    return extra + ([diagram] if diagram else [])
