"""Vectorised O(n) kernels behind the discrete-time STL semantics.

* ``window_min`` / ``window_max``: ``out[k] = min x[k+lo .. min(k+hi, n-1)]`` with the window
  truncated at the end of the trace (identity ``+inf`` / ``-inf`` when it is empty). The bounded case
  is the van Herk / Gil-Werman algorithm: block-wise prefix and suffix extrema, two ``accumulate``
  calls and one ``minimum`` — O(n) whatever the window length.
* ``until``: ``out[k] = max_{t' in [k+lo, k+hi]} min(psi[t'], min phi[k .. t'-1])`` (truncated like
  the windows). It is rewritten, exactly, as ``min(G[0,lo-1] phi, shift_lo(F[0,w] psi & (phi U psi)))``
  with ``w = hi - lo`` (the same decomposition as Donzé, Ferrère & Maler, "Efficient robust monitoring
  for STL", CAV 2013), and the unbounded until is an associative scan of clamp functions
  ``x -> max(p, min(q, x))`` done pairwise-recursively (O(n) work, O(log n) numpy calls).

Min and max never round, so these kernels agree with a naive evaluation to the last bit.

**NaN** (see ``space``): a value is NaN exactly when its window reads a NaN. ``np.minimum``/``maximum``
and their ``accumulate`` propagate NaN, and the van Herk/Gil-Werman halves cover exactly the window,
so the windows need nothing more. The until decomposition is exact for numbers but *not* for NaN (its
unbounded reach reads past the window), so ``until`` evaluates NaN-free copies and then marks the
indices whose window reads a NaN (two more O(n) window passes, only when a NaN is present). The scan
therefore never sees a NaN, and its short (Python loop) and long (numpy) paths cannot differ on one.
"""

from __future__ import annotations

import numpy as np

_SEQUENTIAL_BELOW = 64  # scan length under which a plain loop is cheaper than recursion


def _block_window_min(x: np.ndarray, width: int) -> np.ndarray:
    """``out[j] = min x[j .. j+width-1]`` (truncated at the end), van Herk / Gil-Werman."""
    n = x.size
    if width <= 1 or n == 0:
        return x.copy()
    blocks = -(-n // width) + 1  # one extra block of padding so every window has both halves
    padded = np.full(blocks * width, np.inf)
    padded[:n] = x
    grid = padded.reshape(blocks, width)
    prefix = np.minimum.accumulate(grid, axis=1).ravel()  # min from block start to j
    suffix = np.minimum.accumulate(grid[:, ::-1], axis=1)[:, ::-1].ravel()  # min from j to block end
    return np.minimum(suffix[:n], prefix[width - 1 : width - 1 + n])


def window_min(x: np.ndarray, lo: int, hi: float) -> np.ndarray:
    """Truncated sliding minimum over ``[k+lo, k+hi]``; ``hi`` may be ``inf`` (suffix minimum)."""
    n = x.size
    out = np.full(n, np.inf)
    if lo >= n:
        return out
    if np.isinf(hi):
        window = np.minimum.accumulate(x[::-1])[::-1]
    else:
        window = _block_window_min(x, int(hi) - lo + 1)
    out[: n - lo] = window[lo:]
    return out


def window_max(x: np.ndarray, lo: int, hi: float) -> np.ndarray:
    """Truncated sliding maximum over ``[k+lo, k+hi]`` (identity ``-inf`` for empty windows)."""
    return -window_min(-x, lo, hi)


def _compose(p2: np.ndarray, q2: np.ndarray, p1: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, ...]:
    """Clamp ``(p2, q2)`` after clamp ``(p1, q1)``: ``max(p2, min(q2, max(p1, min(q1, x))))``."""
    return np.maximum(p2, np.minimum(q2, p1)), np.minimum(q2, q1)


def _clamp_scan(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``y[i] = max(p[i], min(q[i], y[i-1]))`` with ``y[-1] = -inf``, as a parallel-prefix scan."""
    n = p.size
    if n < _SEQUENTIAL_BELOW:
        out = np.empty(n)
        acc = -np.inf
        for i in range(n):
            acc = max(p[i], min(q[i], acc))
            out[i] = acc
        return out
    half = n // 2
    pair_p, pair_q = _compose(p[1 : 2 * half : 2], q[1 : 2 * half : 2], p[0 : 2 * half : 2], q[0 : 2 * half : 2])
    odd = _clamp_scan(pair_p, pair_q)  # y at indices 1, 3, 5, ...
    out = np.empty(n)
    out[1 : 2 * half : 2] = odd
    out[0] = p[0]
    evens = np.arange(2, n, 2)
    out[evens] = np.maximum(p[evens], np.minimum(q[evens], odd[: evens.size]))
    return out


def _reach(phi: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Unbounded until of NaN-free traces (the scan)."""
    return _clamp_scan(psi[::-1].copy(), phi[::-1].copy())[::-1].copy()


def unbounded_until(phi: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """``out[k] = max_{t' >= k} min(psi[t'], min phi[k .. t'-1])`` over the whole trace."""
    return until(phi, psi, 0, np.inf)


def until(phi: np.ndarray, psi: np.ndarray, lo: int, hi: float) -> np.ndarray:
    """Truncated bounded (or, with ``hi = inf``, unbounded) until with window ``[k+lo, k+hi]``.

    NaN where the window reads one: ``psi`` at ``k+lo .. k+hi`` or ``phi`` at ``k .. k+hi-1`` (both
    truncated to the trace), for indices whose window is not empty.
    """
    bad_phi, bad_psi = np.isnan(phi), np.isnan(psi)
    if not (bad_phi.any() or bad_psi.any()):
        return _until(phi, psi, lo, hi)
    out = _until(np.where(bad_phi, 0.0, phi), np.where(bad_psi, 0.0, psi), lo, hi)
    n = phi.size
    reads = window_max(bad_psi.astype(float), lo, hi) > 0
    if hi >= 1 and n > 1:
        phi_read = bad_phi.astype(float)
        phi_read[-1] = 0.0  # phi at the last sample is read by no window (t' - 1 <= n - 2)
        reads |= window_max(phi_read, 0, hi - 1) > 0
    reads[max(n - lo, 0):] = False  # empty windows read nothing (value -inf)
    out[reads] = np.nan
    return out


def _until(phi: np.ndarray, psi: np.ndarray, lo: int, hi: float) -> np.ndarray:
    """``until`` of NaN-free traces."""
    n = phi.size
    reach = _reach(phi, psi)
    if not np.isinf(hi):
        reach = np.minimum(reach, window_max(psi, 0, int(hi) - lo))
    shifted = np.full(n, -np.inf)
    if lo < n:
        shifted[: n - lo] = reach[lo:]
    if lo == 0:
        return shifted
    out: np.ndarray = np.minimum(window_min(phi, 0, lo - 1), shifted)
    return out
