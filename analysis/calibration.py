"""The calibration command: fit METANET's fundamental diagram from SUMO detector data
(``corridor.traffic.macro.calibrate``) and draw the fit against the detector points.

    python -m corridor.analysis.calibration scenarios/ramp_metering.yaml [--scale 1.1] [--seed 0]
    python -m corridor.analysis.calibration scenarios/ramp_metering.yaml --html-only

Writes ``<name>.calibration.json`` beside the scenario (``ramp_mpc`` reads it) and the diagram as
``<name>.calibration.html`` (the report's own section, ``corridor.analysis.report_series``).  It lives
in ``analysis`` because it draws: the fit itself imports nothing above ``traffic``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from corridor.analysis.report_series import diagram_section
from corridor.traffic.macro.calibrate import calibrate


def write_diagram_html(json_path: Path) -> Path:
    """Write the fitted diagram against the detector points of a calibration JSON as ``*.html`` beside it."""
    out = json_path.with_suffix(".html")
    out.write_text(f"<!doctype html><html><head><meta charset=utf-8><title>{json_path.name}</title></head>"
                   f"<body style='font-family:sans-serif'>{diagram_section(json_path)}</body></html>")
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scale", type=float, default=1.0, help="demand scale (higher: more congested points)")
    ap.add_argument("--duration", type=float, default=None, help="[s] simulated time (default: scenario's)")
    ap.add_argument("--out", type=Path, default=None,
                    help="calibration JSON (default: <scenario>.calibration.json beside the scenario)")
    ap.add_argument("--html-only", action="store_true",
                    help="only draw the diagram of the existing calibration JSON (no SUMO run)")
    a = ap.parse_args(argv)
    if a.html_only:
        src = a.out or a.scenario.with_suffix("").with_suffix(".calibration.json")
        print(write_diagram_html(src))
        return
    path = calibrate(a.scenario, a.seed, a.scale, a.duration, a.out)
    doc = json.loads(path.read_text())
    print(f"{path}: v_free={doc['v_free_kmh']:.1f} km/h  rho_crit={doc['rho_crit']:.1f} veh/km/lane  "
          f"a={doc['a']:.2f}  capacity={doc['capacity_vph_per_lane']:.0f} veh/h/lane  "
          f"rmse={doc['rmse_kmh']:.1f} km/h  ({doc['n_points']} points); "
          f"ALINEA set point {doc['alinea_setpoint_pct']:.1f} % (downstream loops); "
          f"diagram: {write_diagram_html(path)}")


if __name__ == "__main__":
    main()
