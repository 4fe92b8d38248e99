"""Structure of the ramp MPC's NLP: every row couples only neighbouring segments and steps, sizes
grow linearly with the beltway, and the fill counter agrees with a dense factorization."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
from corridor.controllers.ramp_metering.mpc_structure import (
    beltway_geometry,
    cholesky_fill,
    family_table,
    kkt_matrix,
    kkt_patterns,
    ordering_fill,
)
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway


def _structure(n: int) -> tuple[RampMeteringMPC, sp.csr_matrix, sp.csr_matrix, dict, dict]:
    layout = BeltwayLayout(n_interchanges=n, lanes=2)
    mpc = RampMeteringMPC(beltway(layout), MPCConfig(horizon_ctrl_steps=2))
    jac, hess = kkt_patterns(mpc)
    var, con = beltway_geometry(mpc, layout)
    return mpc, jac, hess, family_table(jac, con, var), family_table(hess, var, var)


@pytest.fixture(scope="module")
def small_and_double() -> tuple[tuple, tuple]:
    return _structure(4), _structure(8)


def test_rows_couple_only_neighbours(small_and_double: tuple) -> None:
    for mpc, _, _, rows, hess in small_and_double:
        seg_km = float(mpc.net.length_km[0])
        for fam, (_, _, dist_km, span) in rows.items():  # a row: its segment and the next ones, one step back
            assert dist_km <= seg_km + 1e-9, fam
            assert span <= mpc.m - 1, fam  # a control is held for one control step
        for fam, (_, _, dist_km, _) in hess.items():  # H: speed rows couple up- and downstream neighbours
            assert dist_km <= 2 * seg_km + 1e-9, fam


def test_nlp_grows_linearly_and_degrees_do_not_grow(small_and_double: tuple) -> None:
    (m4, j4, h4, rows4, hess4), (m8, j8, h8, rows8, hess8) = small_and_double
    assert m8.lay.offsets[-1] == 2 * m4.lay.offsets[-1]
    assert (j8.nnz, h8.nnz) == (2 * j4.nnz, 2 * h4.nnz)
    for a, b in ((rows4, rows8), (hess4, hess8)):
        assert {f: v[:2] for f, v in a.items()} == {f: v[:2] for f, v in b.items()}


def test_fill_count_matches_dense_cholesky() -> None:
    rng = np.random.default_rng(0)
    a = sp.random(40, 40, density=0.06, random_state=rng).tocsr()
    h = a[15:, 15:]
    kkt = kkt_matrix(a[:15, :25], (h + h.T).tocsr())  # 15 constraints on 25 variables
    nnz, flops = cholesky_fill(kkt, None)
    chol = np.linalg.cholesky(kkt.toarray())
    col = (np.abs(chol) > 1e-14).sum(axis=0)  # structural = numerical here (no cancellation by chance)
    assert nnz == int(col.sum()) and flops == float(np.sum(col.astype(float) ** 2))
    assert ordering_fill(kkt, "mmd")[0] <= nnz
    with pytest.raises(ValueError, match="unknown ordering"):
        ordering_fill(kkt, "metis")
