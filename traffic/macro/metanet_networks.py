"""Constructors of METANET networks: the Hegyi benchmark freeway and a two-direction beltway ring.

Beltway routing model (kept simple, stated plainly): every interchange k has one arterial demand
source; a share ``s_k`` of it enters the clockwise (cw) loop, ``1 - s_k`` the counter-clockwise
(ccw) loop, each through its own metered on-ramp with its own queue. Without guidance ``s_k`` is the
destination-oriented share: each OD pair takes its shorter loop (ties split 50/50). Route guidance
may move ``s_k`` within ``default +- compliance``. Off-ramps are static turning fractions computed
from the OD matrix under the default routing, so the model does not track destinations of the
vehicles that were rerouted: diverted drivers leave the other loop like its average driver. This is
a first-order (single-commodity) approximation of destination-oriented METANET.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corridor.traffic.macro.metanet import MetanetNetwork, MetanetParams

# Hegyi, A., De Schutter, B., Hellendoorn, J. (2005). Model predictive control for optimal
# coordination of ramp metering and variable speed limits. Transp. Res. C 13(3), 185-209; and
# Hegyi, A. (2004), PhD thesis, TRAIL, ch. 6. Values as reproduced by the open implementation
# FilippoAiraldi/sym-metanet (examples/ramp_metering_in_casadi.py); the queue limit of 100 veh
# on the on-ramp is the constraint used there.
HEGYI_LANES = 2
HEGYI_SEG_KM = 1.0
HEGYI_V_FREE_KMH = 102.0
HEGYI_RHO_CRIT = 33.5  # [veh/km/lane]
HEGYI_RHO_MAX = 180.0  # [veh/km/lane]
HEGYI_A = 1.867
HEGYI_MAIN_CAP_VPH = 4000.0
HEGYI_RAMP_CAP_VPH = 2000.0
HEGYI_RAMP_STORAGE_VEH = 100.0
HEGYI_RAMP_SEGMENT = 4  # 0-based: the on-ramp feeds the 5th of 6 segments (link L1 = 4 segments)


def _uniform(n: int, value: float) -> np.ndarray:
    return np.full(n, float(value))


def hegyi_freeway(params: MetanetParams | None = None) -> MetanetNetwork:
    """Hegyi benchmark: 6 x 1 km two-lane freeway, mainstream origin, one metered on-ramp.

    d = [mainline demand, on-ramp demand, downstream boundary density].
    """
    n = 6
    return MetanetNetwork(
        name="hegyi2005",
        length_km=_uniform(n, HEGYI_SEG_KM), lanes=_uniform(n, HEGYI_LANES),
        v_free_kmh=_uniform(n, HEGYI_V_FREE_KMH), rho_crit=_uniform(n, HEGYI_RHO_CRIT),
        a=_uniform(n, HEGYI_A), rho_max=_uniform(n, HEGYI_RHO_MAX),
        up=np.arange(n) - 1, down=np.where(np.arange(n) + 1 < n, np.arange(n) + 1, -1),
        exit_frac=np.zeros(n),
        orig_seg=np.array([0, HEGYI_RAMP_SEGMENT]),
        orig_cap_vph=np.array([HEGYI_MAIN_CAP_VPH, HEGYI_RAMP_CAP_VPH]),
        orig_metered=np.array([False, True]), orig_onramp=np.array([False, True]),
        orig_source=np.array([0, 1]), orig_split=np.array([-1, -1]),
        orig_split_a=np.array([False, False]),
        orig_storage_veh=np.array([np.inf, HEGYI_RAMP_STORAGE_VEH]),
        n_sources=2, params=params or MetanetParams(),
        seg_labels=tuple(f"S{i + 1}" for i in range(n)), orig_labels=("O1", "O2"),
    )


def hegyi_demands(time_h: np.ndarray) -> np.ndarray:
    """Disturbances (K, 3) of the benchmark: mainline, on-ramp demand [veh/h], boundary density.

    Mainline 3500 veh/h dropping to 1000 between 2.0 h and 2.25 h; on-ramp 500 -> 1500 veh/h
    (0-0.15 h), held to 0.35 h, back to 500 at 0.5 h; free outflow downstream (density 0).
    """
    main = np.interp(time_h, (2.0, 2.25), (3500.0, 1000.0))
    ramp = np.interp(time_h, (0.0, 0.15, 0.35, 0.5), (500.0, 1500.0, 1500.0, 500.0))
    return np.stack([main, ramp, np.zeros_like(time_h)], axis=1)


def hegyi_initial_state() -> np.ndarray:
    """Initial densities, speeds and queues of the benchmark (Hegyi 2004 / sym-metanet)."""
    rho = [22.0, 22.0, 22.5, 24.0, 30.0, 32.0]
    v = [80.0, 80.0, 78.0, 72.5, 66.0, 62.0]
    return np.array(rho + v + [0.0, 0.0])


@dataclass(frozen=True)
class BeltwayLayout:
    """Geometry and demand of a beltway: what the METANET constructor needs besides the FD."""

    n_interchanges: int = 4
    spacing_km: float = 3.0  # ring length between consecutive interchanges [km]
    seg_target_km: float = 1.0  # target segment length [km]
    lanes: int = 3
    v_free_kmh: float = 102.0
    rho_crit: float = 33.5  # [veh/km/lane]
    a: float = 1.867
    rho_max: float = 180.0  # [veh/km/lane]
    ramp_cap_vph: float = 2000.0
    ramp_storage_veh: float = 60.0
    compliance: float = 0.3  # largest shift of the cw share route guidance can cause [-]
    trip_exponent: float = 0.0  # OD weight hops^exponent (0: uniform over destinations)


def beltway_od(n: int, origin_vph: float, trip_exponent: float = 0.0) -> np.ndarray:
    """OD matrix [veh/h]: each interchange sends origin_vph to the others, weighted by hops^exponent.

    Exponent 0 spreads trips evenly; a positive exponent favours long trips (more ring load per
    entering vehicle, and more drivers with a real choice of loop).
    """
    o, m = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    hops = np.minimum((m - o) % n, (o - m) % n).astype(float)
    w = np.where(hops > 0, np.power(np.maximum(hops, 1.0), trip_exponent), 0.0)
    return origin_vph * w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)


def cw_share_matrix(n: int) -> np.ndarray:
    """Destination-oriented default: 1 if the cw loop is shorter from o to m, 0.5 on ties, else 0."""
    o, m = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    cw_hops, ccw_hops = (m - o) % n, (o - m) % n
    return np.where(cw_hops < ccw_hops, 1.0, np.where(cw_hops == ccw_hops, 0.5, 0.0))


def _link_and_exit_flows(od: np.ndarray, share_cw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Default-routing flows: link[dir, k] leaving interchange k, exit[dir, m] at interchange m."""
    n = od.shape[0]
    link, exit_ = np.zeros((2, n)), np.zeros((2, n))
    for o in range(n):
        for m in range(n):
            if o == m or od[o, m] <= 0:
                continue
            for dirn, share, hop in ((0, share_cw[o, m], 1), (1, 1.0 - share_cw[o, m], -1)):
                if share <= 0:
                    continue
                k = o
                while k != m:
                    link[dirn, k] += od[o, m] * share
                    k = (k + hop) % n
                exit_[dirn, m] += od[o, m] * share
    return link, exit_


def _ring_topology(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """up/down indices of 2 directions x n links x m segments; seg index = (dir*n + link)*m + s."""
    up, down = np.zeros(2 * n * m, dtype=int), np.zeros(2 * n * m, dtype=int)
    for dirn, hop in ((0, 1), (1, -1)):
        for k in range(n):
            for s in range(m):
                i = (dirn * n + k) * m + s
                prev_link, next_link = (k - hop) % n, (k + hop) % n
                up[i] = i - 1 if s > 0 else (dirn * n + prev_link) * m + m - 1
                down[i] = i + 1 if s < m - 1 else (dirn * n + next_link) * m
    return up, down


def beltway(layout: BeltwayLayout | None = None, od_vph: np.ndarray | None = None,
            params: MetanetParams | None = None) -> MetanetNetwork:
    """Two-direction ring with n interchanges, a metered on-ramp per direction and interchange.

    Direction 0 is cw (interchange k -> k+1), 1 is ccw (k -> k-1). Link k of a direction leaves
    interchange k; its last segment carries the off-ramp of the next interchange. Origin 2k is the cw
    on-ramp of interchange k, origin 2k+1 the ccw one; both draw on demand source k, split by u's
    route share s_k (cw share). ``od_vph`` only fixes turning fractions and default splits (its
    scale is irrelevant); the demand itself is the disturbance d (one value per interchange).
    """
    lay = layout or BeltwayLayout()
    n = lay.n_interchanges
    m = max(1, int(round(lay.spacing_km / lay.seg_target_km)))
    od = beltway_od(n, 1000.0, lay.trip_exponent) if od_vph is None else np.asarray(od_vph, dtype=float)
    share_cw = cw_share_matrix(n)
    link, exit_ = _link_and_exit_flows(od, share_cw)
    up, down = _ring_topology(n, m)
    n_seg = 2 * n * m
    exit_frac = np.zeros(n_seg)
    for dirn, hop in ((0, 1), (1, -1)):
        for k in range(n):
            arriving = (k - hop) % n  # link that ends at interchange k
            flow = link[dirn, arriving]
            exit_frac[(dirn * n + arriving) * m + m - 1] = exit_[dirn, k] / flow if flow > 0 else 0.0
    row = od.sum(axis=1)
    split_default = np.where(row > 0, (od * share_cw).sum(axis=1) / np.where(row > 0, row, 1.0), 0.5)
    orig_seg = np.array([(dirn * n + k) * m for k in range(n) for dirn in (0, 1)])
    no = 2 * n
    return MetanetNetwork(
        name=f"beltway{n}",
        length_km=_uniform(n_seg, lay.spacing_km / m), lanes=_uniform(n_seg, lay.lanes),
        v_free_kmh=_uniform(n_seg, lay.v_free_kmh), rho_crit=_uniform(n_seg, lay.rho_crit),
        a=_uniform(n_seg, lay.a), rho_max=_uniform(n_seg, lay.rho_max),
        up=up, down=down, exit_frac=np.clip(exit_frac, 0.0, 1.0),
        orig_seg=orig_seg, orig_cap_vph=_uniform(no, lay.ramp_cap_vph),
        orig_metered=np.ones(no, dtype=bool), orig_onramp=np.ones(no, dtype=bool),
        orig_source=np.repeat(np.arange(n), 2), orig_split=np.repeat(np.arange(n), 2),
        orig_split_a=np.tile([True, False], n), orig_storage_veh=_uniform(no, lay.ramp_storage_veh),
        n_sources=n, split_default=split_default,
        split_lo=np.clip(split_default - lay.compliance, 0.0, 1.0),
        split_hi=np.clip(split_default + lay.compliance, 0.0, 1.0),
        params=params or MetanetParams(),
        seg_labels=tuple(f"{'cw' if i < n * m else 'ccw'}{(i % (n * m)) // m}.{i % m}" for i in range(n_seg)),
        orig_labels=tuple(f"ic{k}.{d}" for k in range(n) for d in ("cw", "ccw")),
    )


def peak_profile(time_h: np.ndarray, base: float = 0.5, peak: float = 1.0, t_peak_h: float = 0.75,
                 width_h: float = 0.35) -> np.ndarray:
    """Smooth peak-hour multiplier: base + (peak - base) exp(-((t - t_peak)/width)^2) [-]."""
    return base + (peak - base) * np.exp(-(((time_h - t_peak_h) / width_h) ** 2))


def beltway_demands(time_h: np.ndarray, origin_peak_vph: np.ndarray | float, n: int) -> np.ndarray:
    """Disturbances (K, n): arterial demand of each interchange [veh/h] following ``peak_profile``."""
    peak = np.broadcast_to(np.asarray(origin_peak_vph, dtype=float), (n,))
    return peak_profile(time_h)[:, None] * peak[None, :]


def beltway_demand_for_load(layout: BeltwayLayout, load: float = 1.0) -> float:
    """Per-interchange demand [veh/h] (uniform OD) that loads the busiest ring link to ``load`` x capacity.

    Capacity per lane is the METANET one, V(rho_crit) rho_crit = v_free rho_crit exp(-1/a).
    """
    n = layout.n_interchanges
    link, _ = _link_and_exit_flows(beltway_od(n, 1.0, layout.trip_exponent), cw_share_matrix(n))
    cap_vph = layout.lanes * layout.v_free_kmh * layout.rho_crit * float(np.exp(-1.0 / layout.a))
    return load * cap_vph / float(link.max())
