"""CasADi's OpenBLAS thread count: set for a block and restored; the MPC's result does not depend on it."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.ramp_metering.casadi_blas import blas_threads, casadi_blas_threads
from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
from corridor.traffic.metanet import steady_state
from corridor.traffic.metanet_networks import BeltwayLayout, beltway


def test_threads_set_for_the_block_and_restored() -> None:
    before = blas_threads()
    if before is None:
        pytest.skip("this CasADi build bundles no OpenBLAS")
    with casadi_blas_threads(1):
        assert blas_threads() == 1
    assert blas_threads() == before
    with pytest.raises(RuntimeError), casadi_blas_threads(1):
        raise RuntimeError("solver failed")
    assert blas_threads() == before
    with casadi_blas_threads(None):
        assert blas_threads() == before


def test_bad_thread_count_is_refused() -> None:
    if blas_threads() is None:
        pytest.skip("this CasADi build bundles no OpenBLAS")
    with pytest.raises(ValueError, match=">= 1"), casadi_blas_threads(0):
        pass


def test_mpc_result_does_not_depend_on_blas_threads() -> None:
    net = beltway(BeltwayLayout(n_interchanges=3, lanes=2, ramp_storage_veh=40.0))
    x0 = steady_state(net, 30.0)
    x0[2 * net.n_seg:] = 20.0
    demand = np.full(net.nd, 2400.0)  # [veh/h] per interchange
    res = [RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, blas_threads=t)).solve(x0, demand)
           for t in (1, None)]
    assert not res[0].fallback and not res[1].fallback
    np.testing.assert_allclose(res[0].u, res[1].u, atol=1e-6)
    assert res[0].predicted_tts == pytest.approx(res[1].predicted_tts, rel=1e-9)
