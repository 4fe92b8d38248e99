"""A PNG of a parking case and its trajectory (matplotlib, headless): obstacles, footprints along the
path (forward blue, reverse red), start and goal footprints."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from corridor.controllers.parking.geometry import TPCAP_VEHICLE, VehicleGeometry, footprint


def plot_case(path: str | Path, start: Sequence[float], goal: Sequence[float], obstacles: Sequence[np.ndarray],
              traj: np.ndarray | None = None, vehicle: VehicleGeometry = TPCAP_VEHICLE,
              title: str = "") -> Path:
    """Write the PNG; ``traj`` is (n, ≥5) with columns t, x, y, theta, v."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    fig, ax = plt.subplots(figsize=(7, 7))
    for poly in obstacles:
        ax.add_patch(Polygon(np.asarray(poly), closed=True, fc="0.6", ec="k"))
    if traj is not None and len(traj):
        every = max(1, len(traj) // 40)
        for row in traj[::every]:
            fp = footprint(row[1:4][None], vehicle)[0]
            ax.add_patch(Polygon(fp, closed=True, fill=False, lw=0.5, ec="tab:blue" if row[4] >= 0 else "tab:red"))
        ax.plot(traj[:, 1], traj[:, 2], "k-", lw=1)
    for pose, colour in ((start, "tab:green"), (goal, "tab:purple")):
        ax.add_patch(Polygon(footprint(np.asarray(pose, float)[None], vehicle)[0], closed=True, fill=False,
                             lw=2, ec=colour))
    pts = np.vstack([np.asarray(p) for p in obstacles] + [np.asarray([start[:2], goal[:2]])])
    if traj is not None and len(traj):
        pts = np.vstack([pts, traj[:, 1:3]])
    lo, hi = pts.min(axis=0) - 3, pts.max(axis=0) + 3
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    out = Path(path)
    fig.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return out
