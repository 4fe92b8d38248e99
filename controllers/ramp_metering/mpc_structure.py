"""Structure of the ramp MPC's NLP: KKT sparsity, what each row couples, and the factorization's fill.

IPOPT spends ~95 % of a ramp-MPC solve factorizing the KKT matrix [[H + Sigma, J'], [J, -delta]]
(H: Hessian of the Lagrangian, J: constraint Jacobian).  This module gives the structural J and H of
a ``RampMeteringMPC``, places every variable and constraint row on the beltway ring [km] and on the
horizon [model steps] so one can check that a row couples only neighbouring segments and steps, and
counts the fill of a symbolic Cholesky factorization of the KKT pattern under a given ordering.
``benchmarks/mpc_kkt_structure.py`` prints these figures per network size.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.sparse.linalg import splu

from corridor.controllers.ramp_metering.mpc import RampMeteringMPC
from corridor.traffic.macro.metanet_networks import BeltwayLayout


@dataclass(frozen=True)
class Geometry:
    """Position on the ring [km], time [model steps] and family name of every KKT node."""

    pos_km: np.ndarray
    t0: np.ndarray  # first model step the node belongs to
    t1: np.ndarray  # last model step (controls span a control step)
    family: np.ndarray
    ring_km: float


def beltway_geometry(mpc: RampMeteringMPC, layout: BeltwayLayout) -> tuple[Geometry, Geometry]:
    """(variables, constraints) geometry in the order of z and g."""
    net, lay = mpc.net, mpc.lay
    n, sp_km = layout.n_interchanges, layout.spacing_km
    m = net.n_seg // (2 * n)
    seg = np.arange(net.n_seg)
    dirn, k, s = seg // (n * m), (seg // m) % n, seg % m
    seg_km = np.where(dirn == 0, k * sp_km + (s + 0.5) * net.length_km, k * sp_km - (s + 0.5) * net.length_km)
    orig_km = np.repeat(np.arange(n), 2) * sp_km
    x_km = np.concatenate([seg_km, seg_km, orig_km])
    x_fam = np.array(["rho"] * net.n_seg + ["v"] * net.n_seg + ["w"] * net.n_orig)
    pos, t0, t1, fam = [], [], [], []
    for kk in range(lay.n):  # X column kk is the state after model step kk
        pos.append(x_km), t0.append(np.full(lay.nx, kk)), t1.append(np.full(lay.nx, kk)), fam.append(x_fam)
    r_km, s_km = orig_km[net.metered_idx], np.arange(n) * sp_km
    for j in range(lay.nc):
        pos.append(r_km), t0.append(np.full(lay.nr, j * mpc.m)), t1.append(np.full(lay.nr, j * mpc.m + mpc.m - 1))
        fam.append(np.array(["R"] * lay.nr))
    for j in range(lay.nc):
        pos.append(s_km), t0.append(np.full(lay.ns, j * mpc.m)), t1.append(np.full(lay.ns, j * mpc.m + mpc.m - 1))
        fam.append(np.array(["S"] * lay.ns))
    q_km = orig_km[mpc.queue_idx]
    for kk in range(lay.n):
        pos.append(q_km), t0.append(np.full(lay.nq, kk)), t1.append(np.full(lay.nq, kk)), fam.append(np.array(["sig"] * lay.nq))
    ring = n * sp_km
    var = Geometry(np.mod(np.concatenate(pos), ring), np.concatenate(t0), np.concatenate(t1), np.concatenate(fam), ring)
    gp, gt, gf = [], [], []
    for kk in range(lay.n):  # g = [dynamics(k) (nx), queue rows(k) (nq)] per model step
        gp += [x_km, q_km]
        gt += [np.full(lay.nx, kk), np.full(lay.nq, kk)]
        gf += [np.char.add("dyn_", x_fam), np.array(["queue"] * lay.nq)]
    t = np.concatenate(gt)
    con = Geometry(np.mod(np.concatenate(gp), ring), t, t, np.concatenate(gf), ring)
    return var, con


def kkt_patterns(mpc: RampMeteringMPC) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Structural (J, H) of the MPC's NLP: constraint Jacobian and full Hessian of the Lagrangian."""
    nlp = mpc.nlp
    z, g, f = nlp["x"], nlp["g"], nlp["f"]
    lam = ca.SX.sym("lam", g.shape[0])
    jac = ca.jacobian(g, z).sparsity()
    hess = ca.hessian(f + ca.dot(lam, g), z)[0].sparsity()

    def to_csr(s: ca.Sparsity) -> sp.csr_matrix:
        r, c = s.get_triplet()
        return sp.csr_matrix((np.ones(len(r)), (r, c)), shape=s.shape)

    return to_csr(jac), to_csr(hess)


def _ring_dist(a: np.ndarray, b: np.ndarray, ring: float) -> np.ndarray:
    d = np.abs(a - b) % ring
    return np.minimum(d, ring - d)


def _row_spans(mat: sp.csr_matrix, rows: Geometry, cols: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Largest ring distance [km] and time span [steps] between a row's own node and its columns."""
    coo = mat.tocoo()
    dist = _ring_dist(rows.pos_km[coo.row], cols.pos_km[coo.col], rows.ring_km)
    tspan = np.maximum(np.abs(rows.t0[coo.row] - cols.t1[coo.col]), np.abs(rows.t1[coo.row] - cols.t0[coo.col]))
    d_max, t_max = np.zeros(mat.shape[0]), np.zeros(mat.shape[0])
    np.maximum.at(d_max, coo.row, dist)
    np.maximum.at(t_max, coo.row, tspan)
    return d_max, t_max


def family_table(mat: sp.csr_matrix, rows: Geometry, cols: Geometry) -> dict[str, tuple[float, int, float, float]]:
    """Per row family of ``mat`` (rows located by ``rows``, columns by ``cols``): (mean degree, max degree, max ring distance [km], max time span [steps])."""
    deg = np.diff(mat.indptr)
    d_max, t_max = _row_spans(mat, rows, cols)
    out = {}
    for fam in dict.fromkeys(rows.family.tolist()):
        sel = rows.family == fam
        out[fam] = (float(deg[sel].mean()), int(deg[sel].max()), float(d_max[sel].max()), float(t_max[sel].max()))
    return out


def kkt_matrix(jac: sp.csr_matrix, hess: sp.csr_matrix) -> sp.csc_matrix:
    """Symmetric positive definite matrix with the KKT pattern (diagonally dominant: no pivoting)."""
    nz, ng = hess.shape[0], jac.shape[0]
    pat = sp.bmat([[hess + sp.eye(nz), jac.T], [jac, sp.eye(ng)]]).tocsr()
    pat.data[:] = -1.0
    pat = pat + pat.T
    pat.data[:] = -1.0
    deg = np.diff(pat.indptr)
    return (pat + sp.diags(deg + 2.0)).tocsc()


def cholesky_fill(a: sp.csc_matrix, perm: np.ndarray | None, spec: str = "NATURAL") -> tuple[int, float]:
    """(nnz(L), flops sum(colcount^2)) of the Cholesky pattern of a (symmetrically permuted by perm)."""
    if perm is not None:
        a = a[perm][:, perm].tocsc()
    lu = splu(a, permc_spec=spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    col = np.diff(lu.L.tocsc().indptr).astype(float)
    return int(lu.L.nnz), float(np.sum(col**2))


def ordering_fill(kkt: sp.csc_matrix, ordering: str) -> tuple[int, float]:
    """``cholesky_fill`` under "mmd" (SuperLU's minimum degree on A'+A), "colamd" or "rcm" (reverse
    Cuthill-McKee: a band along the ring)."""
    if ordering == "rcm":
        return cholesky_fill(kkt, reverse_cuthill_mckee(kkt.tocsr(), symmetric_mode=True))
    specs = {"mmd": "MMD_AT_PLUS_A", "colamd": "COLAMD"}
    if ordering not in specs:
        raise ValueError(f"unknown ordering {ordering!r}: choose mmd, colamd or rcm")
    return cholesky_fill(kkt, None, specs[ordering])
