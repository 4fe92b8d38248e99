"""The station scale of the ramp MPC's density state, and the map between it and segment-mean density.

The METANET model of ``ramp_mpc`` is calibrated on loop-station points (``calibrate``: rho_crit ~41
veh/km/lane from the stations at the merges), and its state comes from the stations by the direct
mapping (the mean of the station downstream of merge k and the one upstream of the next merge).  The
stations sit where the merges are, so in dense traffic they read well above the segment's mean
density (the quantity a camera counts and ``segment_watch`` calls truth): on ``air_ground_watch`` with
healthy loops, segments with 30-40 veh/km/lane of vehicles read ~43 at the stations.  An MPC fed the
segment-mean truth therefore sees the merges below critical and meters too little (seeds 0/1: TTS of
the perfect-information MPC no better than with 30 % of the loops failed).

``StationMap`` is the monotone, piecewise-linear map ``g``: segment-mean density -> the direct
mapping's reading at the same instant (bin medians of paired samples from healthy-loop runs, made
monotone).  The fusion takes loop readings to the segment scale with ``g^-1`` (its state is the
segment mean, as the cameras measure it) and the MPC takes the estimate to its model's station scale
with ``g``.

    python -m corridor.traffic.macro.station_map RESULTS_DIR [...] --out scenarios/NAME.station_map.json

fits it from the ``rho_true_i`` / ``mpc_rho_i`` signals of the ``loops`` runs of batches (the MPC on
the direct mapping).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BIN_WIDTH = 5.0  # [veh/km/lane]
MIN_PER_BIN = 20  # samples for a bin to count


@dataclass(frozen=True)
class StationMap:
    """Monotone piecewise-linear g: segment-mean density -> station-scale density [veh/km/lane]."""

    segment: tuple[float, ...]  # breakpoints (strictly increasing), segment-mean density
    station: tuple[float, ...]  # g at the breakpoints (strictly increasing)
    residual_sd: float = 0.0  # [veh/km/lane] sd of the station readings about g (segment scale: / slope)
    source: str = ""

    def to_station(self, rho_segment: np.ndarray) -> np.ndarray:
        """g(rho); beyond the last breakpoint (no data) station and segment density move one to one."""
        return _interp_lin(np.asarray(rho_segment, float), np.asarray(self.segment), np.asarray(self.station))

    def to_segment(self, rho_station: np.ndarray) -> np.ndarray:
        """g^-1(rho) (floored at 0)."""
        out = _interp_lin(np.asarray(rho_station, float), np.asarray(self.station), np.asarray(self.segment))
        return np.maximum(out, 0.0)

    @staticmethod
    def load(path: str | Path) -> StationMap:
        d = json.loads(Path(path).read_text())
        return StationMap(tuple(d["segment"]), tuple(d["station"]), float(d.get("residual_sd", 0.0)), str(path))


def _interp_lin(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp, continued with slope 1 outside the breakpoints: beyond the densest bin the data say
    nothing (there the stations saturate near 50 veh/km/lane, and the last segment's slope ~0.1 would
    blow a station reading of 60 up to a segment density of ~130 through the inverse)."""
    y = np.interp(x, xp, fp)
    y = np.where(x < xp[0], fp[0] + (x - xp[0]), y)
    return np.where(x > xp[-1], fp[-1] + (x - xp[-1]), y)


def fit_station_map(truth: np.ndarray, station: np.ndarray, bin_width: float = BIN_WIDTH,
                    min_per_bin: int = MIN_PER_BIN) -> StationMap:
    """Bin medians of ``station`` against ``truth`` (bins of ``bin_width`` with at least ``min_per_bin``
    samples), anchored at (0, 0) and made strictly increasing."""
    truth, station = np.asarray(truth, float), np.asarray(station, float)
    ok = np.isfinite(truth) & np.isfinite(station)
    truth, station = truth[ok], station[ok]
    xs, ys = [0.0], [0.0]
    for lo in np.arange(0.0, float(truth.max(initial=0.0)) + bin_width, bin_width):
        m = (truth >= lo) & (truth < lo + bin_width)
        if m.sum() >= min_per_bin:
            xs.append(float(np.median(truth[m])))
            ys.append(float(np.median(station[m])))
    if len(xs) < 3:
        raise ValueError(f"need samples in at least 2 density bins of {bin_width:g} veh/km/lane, got {len(xs) - 1}")
    y = np.maximum.accumulate(np.asarray(ys))
    y = y + 1e-3 * np.arange(len(y))  # strictly increasing: g^-1 exists
    g = StationMap(tuple(xs), tuple(float(v) for v in y))
    sd = float(np.sqrt(np.mean((station - g.to_station(truth)) ** 2)))
    return StationMap(g.segment, g.station, sd)


def paired_samples(npz_files: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """(truth, station) pairs from runs' signals: ``rho_true_i`` against the MPC's input ``mpc_rho_i``
    recorded at the same instant (the MPC on the direct mapping)."""
    xs, ys = [], []
    for f in npz_files:
        z = np.load(f)
        i = 0
        while f"rho_true_{i}" in z and f"mpc_rho_{i}" in z:
            tt, rt, tm, rm = z[f"rho_true_{i}.t"], z[f"rho_true_{i}"], z[f"mpc_rho_{i}.t"], z[f"mpc_rho_{i}"]
            j = np.searchsorted(tm, tt)
            hit = (j < len(tm)) & (np.abs(tm[np.minimum(j, len(tm) - 1)] - tt) < 1.0)
            xs.append(rt[hit])
            ys.append(rm[np.minimum(j, len(tm) - 1)][hit])
            i += 1
    if not xs:
        raise ValueError("no rho_true_i / mpc_rho_i signal pairs in the given runs")
    return np.concatenate(xs), np.concatenate(ys)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batches", nargs="+", help="batch folders (their signals/<variant>-s<seed>.npz)")
    ap.add_argument("--variant", default="loops", help="runs of this variant (healthy loops, direct mapping)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    files = sorted(f for b in a.batches for f in Path(b, "signals").glob(f"{a.variant}-s*.npz"))
    if not files:
        raise SystemExit(f"error: no signals/{a.variant}-s*.npz in {a.batches}")
    truth, station = paired_samples(files)
    g = fit_station_map(truth, station)
    out = {"segment": list(g.segment), "station": list(g.station), "residual_sd": g.residual_sd,
           "samples": int(len(truth)), "runs": [f.name for f in files],
           "made_by": "python -m corridor.traffic.macro.station_map " + " ".join(a.batches) + f" --variant {a.variant}"}
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"{a.out}: {len(g.segment)} breakpoints from {len(truth)} samples of {len(files)} runs, "
          f"residual sd {g.residual_sd:.1f} veh/km/lane")


if __name__ == "__main__":
    main()
