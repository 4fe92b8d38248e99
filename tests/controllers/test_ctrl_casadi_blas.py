"""CasADi's OpenBLAS thread count: set by the MPC, refused when invalid; the MPC's result does not
depend on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from corridor.controllers.ramp_metering.casadi_blas import blas_threads, set_casadi_blas_threads
from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
from corridor.traffic.macro.metanet import steady_state
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway


def _case() -> tuple:
    net = beltway(BeltwayLayout(n_interchanges=3, lanes=2, ramp_storage_veh=40.0))
    x0 = steady_state(net, 30.0)
    x0[2 * net.n_seg:] = 20.0
    return net, x0, np.full(net.nd, 2400.0)  # [veh/h] per interchange


@pytest.fixture
def keep_threads():
    before = blas_threads()
    if before is None:
        pytest.skip("this CasADi build bundles no OpenBLAS")
    yield before
    set_casadi_blas_threads(before)


def test_threads_set_and_left_alone(keep_threads: int) -> None:
    set_casadi_blas_threads(2)
    assert blas_threads() == 2
    set_casadi_blas_threads(None)
    assert blas_threads() == 2
    with pytest.raises(ValueError, match=">= 1"):
        set_casadi_blas_threads(0)
    net, x0, demand = _case()
    RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=2, blas_threads=1)).solve(x0, demand)
    assert blas_threads() == 1


def test_mpc_result_does_not_depend_on_blas_threads(keep_threads: int) -> None:
    net, x0, demand = _case()
    res = []
    for threads in (1, 2):
        set_casadi_blas_threads(threads)
        res.append(RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, blas_threads=None)).solve(x0, demand))
    assert not res[0].fallback and not res[1].fallback
    np.testing.assert_allclose(res[0].u, res[1].u, atol=1e-6)
    assert res[0].predicted_tts == pytest.approx(res[1].predicted_tts, rel=1e-9)


def test_one_copy_of_casadi_openblas_is_mapped(keep_threads: int) -> None:
    """The thread count is set on the copy MUMPS uses (pip installs the .so files as copies)."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        pytest.skip("needs /proc/self/maps")
    net, x0, demand = _case()
    RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=2)).solve(x0, demand)
    mapped = {line.split()[-1] for line in maps.read_text().splitlines() if "libcasadi-tp-openblas" in line}
    assert len(mapped) == 1
