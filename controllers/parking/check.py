"""Independent checker of a parking trajectory against its TPCAP case.

Independent of the planner: footprints are built here and tested with shapely (the planner clips
edges in numpy), poses are interpolated between rows to at most 0.02 m / 0.01 rad apart, and limits
are read both from the columns and from finite differences of the rows. It checks:

- the CSV: header ``t,x,y,theta,v,a,steer``, finite numbers, increasing t, steps of at most 0.1 s;
- start and goal: first and last rows within 0.1 m and 0.05 rad of the case's poses;
- limits: |v|, |a|, |steer| from the columns; acceleration, steering rate and speed from differences;
- kinematics: each row follows from the previous one by the bicycle model (within 0.01 m, 0.002 rad);
- collisions: the footprint against every polygon, densely along the path.

``python -m corridor.controllers.parking.check CASE.csv TRAJ.csv``: exit 0 when it passes, 1 with the
violations (one per line), 2 on unreadable input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import shapely

from corridor.controllers.parking.case import Case, CaseError, read_case
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, VehicleGeometry

HEADER = ["t", "x", "y", "theta", "v", "a", "steer"]
EPS = 1e-6  # slack on limits for rounding in the CSV
KIN_TOL_M, KIN_TOL_RAD = 0.01, 0.002  # per row: the bicycle model from the previous row


def read_trajectory(path: str | Path) -> np.ndarray:
    """(n, 7) array from a trajectory CSV; ValueError (one line) if unreadable."""
    p = Path(path)
    try:
        lines = p.read_text().strip().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p}: cannot read ({exc.__class__.__name__})") from None
    if not lines or [h.strip() for h in lines[0].split(",")] != HEADER:
        raise ValueError(f"{p}: the header must be {','.join(HEADER)}")
    try:
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], dtype=float)
    except ValueError:
        raise ValueError(f"{p}: rows must be 7 numbers each") from None
    if data.ndim != 2 or data.shape[1] != 7 or len(data) < 1:
        raise ValueError(f"{p}: need at least one row of 7 numbers")
    return data


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _poses_between(tr: np.ndarray, step_m: float, step_rad: float) -> np.ndarray:
    """Rows' poses with linear interpolation between them, at most step_m / step_rad apart."""
    x, y, th = tr[:, 1], tr[:, 2], np.unwrap(tr[:, 3])
    if len(tr) == 1:
        return np.column_stack([x, y, th])
    n = np.maximum(1, np.ceil(np.maximum(np.hypot(np.diff(x), np.diff(y)) / step_m,
                                         np.abs(np.diff(th)) / step_rad))).astype(int)
    k = np.repeat(np.arange(len(n)), n)
    f = np.concatenate([np.arange(m) / m for m in n])
    out = np.column_stack([x[k] + f * np.diff(x)[k], y[k] + f * np.diff(y)[k], th[k] + f * np.diff(th)[k]])
    return np.vstack([out, [[x[-1], y[-1], th[-1]]]])


def _footprints(poses: np.ndarray, veh: VehicleGeometry) -> np.ndarray:
    along = np.array([-veh.rear_hang_m, veh.wheelbase_m + veh.front_hang_m])
    across = np.array([-veh.width_m / 2, veh.width_m / 2])
    corners = [(along[0], across[0]), (along[1], across[0]), (along[1], across[1]), (along[0], across[1])]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    pts = [np.column_stack([poses[:, 0] + c * a - s * b, poses[:, 1] + s * a + c * b]) for a, b in corners]
    return shapely.polygons(np.stack(pts, axis=1))


def collisions(case: Case, tr: np.ndarray, veh: VehicleGeometry) -> list[str]:
    poses = _poses_between(tr, 0.02, 0.01)
    tree = shapely.STRtree([shapely.Polygon(p) for p in case.obstacles])
    fp = _footprints(poses, veh)
    hits = tree.query(fp, predicate="intersects")
    if hits.shape[1] == 0:
        return []
    first = int(hits[0].min())
    obst = sorted({int(o) for o in hits[1]})
    area = shapely.area(shapely.intersection(fp[hits[0]], tree.geometries[hits[1]])).max()
    return [f"collision: {len(np.unique(hits[0]))} of {len(poses)} checked poses meet obstacle(s) {obst} "
            f"(first at x={poses[first, 0]:.3f}, y={poses[first, 1]:.3f}; largest overlap {area:.4f} m^2)"]


def limits(tr: np.ndarray, veh: VehicleGeometry) -> list[str]:
    t, x, y, th, v, a, steer = tr.T
    dt = np.diff(t)
    out = []
    for name, val, lim in (("|v|", v, veh.max_speed_mps), ("|a|", a, veh.max_accel_mps2),
                           ("|steer|", steer, veh.max_steer_rad),
                           ("|dv/dt|", np.diff(v) / dt, veh.max_accel_mps2),
                           ("|dsteer/dt|", np.diff(steer) / dt, veh.max_steer_rate_rps),
                           ("speed from positions", np.hypot(np.diff(x), np.diff(y)) / dt, veh.max_speed_mps)):
        worst = float(np.max(np.abs(val)))
        if worst > lim + EPS:
            out.append(f"limit: {name} reaches {worst:.4f} > {lim:g}")
    # bicycle model from each row to the next (v and steer linear within the step, RK4 in 8 sub-steps)
    px, py, pth = x[:-1].copy(), y[:-1].copy(), th[:-1].copy()
    m = 8
    for j in range(m):
        def f(fr: float, th_: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            vv = v[:-1] + fr * np.diff(v)
            dd = steer[:-1] + fr * np.diff(steer)
            return vv * np.cos(th_), vv * np.sin(th_), vv * np.tan(dd) / veh.wheelbase_m
        h = dt / m
        f0, f1 = j / m, (j + 0.5) / m
        k1 = f(f0, pth)
        k2 = f(f1, pth + h / 2 * k1[2])
        k3 = f(f1, pth + h / 2 * k2[2])
        k4 = f((j + 1) / m, pth + h * k3[2])
        px = px + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        py = py + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        pth = pth + h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    perr = np.hypot(px - x[1:], py - y[1:])
    therr = np.abs(_wrap(pth - th[1:]))
    if perr.max() > KIN_TOL_M or therr.max() > KIN_TOL_RAD:
        k = int(np.argmax(perr / KIN_TOL_M + therr / KIN_TOL_RAD))
        out.append(f"kinematics: row {k + 1} is {perr[k]:.4f} m / {therr[k]:.4f} rad away from the bicycle "
                   f"model driven from row {k} (tolerance {KIN_TOL_M} m / {KIN_TOL_RAD} rad)")
    return out


def check(case: Case, tr: np.ndarray, veh: VehicleGeometry = TPCAP_VEHICLE, pos_tol_m: float = 0.1,
          heading_tol_rad: float = 0.05, max_dt_s: float = 0.1) -> list[str]:
    """Violations (empty when the trajectory passes)."""
    if not np.all(np.isfinite(tr)):
        return ["format: non-finite numbers"]
    dt = np.diff(tr[:, 0])
    out = []
    if len(tr) == 1:  # the goal is the start: standing still at it
        if tr[0, 4] != 0 or tr[0, 5] != 0:
            out.append("format: a one-row trajectory must stand still (v = a = 0)")
    elif np.any(dt <= 0) or dt.max() > max_dt_s + 1e-9:
        out.append(f"format: time steps must be in (0, {max_dt_s:g}] s (found {dt.min():.4g}..{dt.max():.4g})")
        return out
    for name, row, pose in (("start", tr[0], case.start), ("goal", tr[-1], case.goal)):
        dp = float(np.hypot(row[1] - pose[0], row[2] - pose[1]))
        dth = float(abs(_wrap(row[3] - pose[2])))
        if dp > pos_tol_m or dth > heading_tol_rad:
            out.append(f"{name}: pose off by {dp:.4f} m and {dth:.4f} rad (tolerance {pos_tol_m} m, {heading_tol_rad} rad)")
    return out + (limits(tr, veh) if len(tr) > 1 else []) + collisions(case, tr, veh)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m corridor.controllers.parking.check", description=__doc__.split("\n")[0])
    ap.add_argument("case")
    ap.add_argument("trajectory")
    args = ap.parse_args(argv)
    try:
        case, tr = read_case(args.case), read_trajectory(args.trajectory)
    except (CaseError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    bad = check(case, tr)
    for line in bad:
        print(line)
    if not bad:
        print(f"OK: {len(tr)} rows, {tr[-1, 0] - tr[0, 0]:.1f} s, no collision, limits and goal met")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
