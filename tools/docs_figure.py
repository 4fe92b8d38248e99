"""Make the docs' pictures: docs/assets/uav_encounter.png (the front page) and docs/assets/tpcap_case1.png.

One seed of ``scenarios/uav_encounter.yaml`` (crossing geometry, 45 s) in its three variants, run
through ``corridor.api.run``; the picture is drawn from the runs' recorded signals only:
left, the two quadcopters' and the c172x's tracks seen from above (as the link's Kalman tracks record
them); right, the smallest 3-D separation between any two aircraft over time, per variant.

The second is the parking planner's own plot of TPCAP case 1 (``corridor.controllers.parking.tpcap
--plot``).  The scenario pages also show plots of corridor's batch report as it draws them (inline SVG
in ``report.html``), cut out of the reports of short batches: docs/assets/<scenario>_<plot>.svg.

    python tools/docs_figure.py [--assets docs/assets] [--seed 0]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from corridor.api import run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("none", "potential_field", "control_tube")
COLOURS = {"none": "tab:red", "potential_field": "tab:blue", "control_tube": "tab:green"}
SETS = ["duration=45", "backends.air.params.encounter.geometry=1"]  # crossing, the encounter at 25 s


def draw(signals: dict[str, dict], out: Path) -> None:
    """Tracks from above (left) and the smallest 3-D separation over time (right), one colour a variant."""
    fig, (top, sep) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=100)
    for variant, s in signals.items():
        c = COLOURS[variant]
        for who, style in (("uav_a", "-"), ("uav_b", "--")):
            top.plot(s[f"track_e_{who}"], s[f"track_n_{who}"], style, color=c, lw=1.4,
                     label=f"{variant}" if who == "uav_a" else None)
        sep.plot(s["min_sep_3d.t"], s["min_sep_3d"], color=c, lw=1.6, label=variant)
    c172 = next(iter(signals.values()))
    top.plot(c172["track_e_c172"], c172["track_n_c172"], ":", color="0.4", lw=1.2, label="c172x")
    top.set(xlabel="east [m]", ylabel="north [m]", title="UAV tracks from above (solid a, dashed b)",
            xlim=(-150, 150), ylim=(-150, 150), aspect="equal")
    top.legend(fontsize=8, loc="lower right")
    sep.set(xlabel="time [s]", ylabel="smallest 3-D separation [m]", title="closest pair of aircraft",
            ylim=(0, None))
    sep.legend(fontsize=8)
    fig.suptitle("corridor: uav_encounter, one seed, three avoidance variants (JSBSim + MAVLink 2)", fontsize=11)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


# scenario -> (--set overrides, variants, {report section title: asset name})
REPORT_PLOTS: dict[str, tuple[list[str], list[str], dict[str, str]]] = {
    "merging": (["duration=300"], [], {"Mean speed": "merging_mean_speed",
                                       "Time lost around the merge": "merging_merge_loss"}),
    "merge_bottleneck": ([], ["eidm_human"], {"Bottleneck: breakdown and capacity drop (virtual loops)":
                                               "merge_bottleneck_loop_flows"}),
    "ramp_metering": (["duration=1200"], ["mpc"], {"Mainline speed contour": "ramp_metering_contour",
                                                   "Meter rates": "ramp_metering_meter_rates"}),
}


def report_svg(html: str, title: str) -> str:
    """The first inline SVG of the report section headed ``title`` (a ValueError if there is none)."""
    start = html.find(f"<h2>{title}</h2>")
    found = re.search(r"<svg.*?</svg>", html[start:], flags=re.S) if start >= 0 else None
    if found is None:
        raise ValueError(f"report.html has no plot under {title!r}")
    return found.group(0)


def report_plots(assets: Path, tmp: Path, seed: int) -> list[Path]:
    """Run each scenario of ``REPORT_PLOTS`` briefly and keep the named plots of its report."""
    written = []
    for name, (sets, variants, plots) in REPORT_PLOTS.items():
        res = run(ROOT / "scenarios" / f"{name}.yaml", runs=1, seed=seed, sets=sets, variants=variants,
                  out=tmp / name)
        html = (res.out / "report.html").read_text(encoding="utf-8")
        for title, asset in plots.items():
            path = assets / f"{asset}.svg"
            path.write_text(report_svg(html, title) + "\n", encoding="utf-8")
            written.append(path)
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--assets", type=Path, default=ROOT / "docs" / "assets")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-reports", action="store_true", help="skip the report plots of the scenario pages")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        res = run(ROOT / "scenarios" / "uav_encounter.yaml", runs=1, seed=args.seed, sets=SETS,
                  out=Path(tmp) / "batch", report=False)
        if len(res.failed):
            raise SystemExit(f"a run failed: {res.failed[['run_id', 'error']].to_string()}")
        signals = {v: res.signals(f"{v}-s{args.seed}") for v in VARIANTS}
        draw(signals, args.assets / "uav_encounter.png")
        case = ROOT / "tests" / "data" / "tpcap" / "Case1.csv"
        subprocess.run([sys.executable, "-m", "corridor.controllers.parking.tpcap", str(case), "--out",
                        str(Path(tmp) / "traj.csv"), "--plot", str(args.assets / "tpcap_case1.png")], check=True)
        written = [] if args.no_reports else report_plots(args.assets, Path(tmp), args.seed)
    print(f"{args.assets}/uav_encounter.png, {args.assets}/tpcap_case1.png", *written)


if __name__ == "__main__":
    main()
