"""Reeds–Shepp shortest paths for a car of minimum turning radius R, forward and reverse.

The path families (CSC, CCC, CCCC, CCSC, CCSCC) follow Reeds & Shepp (1990) as laid out in
PythonRobotics' planner; every family is evaluated vectorised over many relative poses at once (the
search's heuristic asks for a batch of children per expansion). The other 44 words come from the 12
base families by time-flip (x, y, φ) -> (-x, y, -φ) and reflection (x, y, φ) -> (x, -y, -φ).

Lengths are in units of R inside this module (unit turning radius) and in metres at its API. Every
candidate path is verified by integrating it and comparing its end with the goal (`paths`), so a
family that is wrong for some pose can only cost optimality, never a wrong path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

PI = np.pi
Family = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, list[np.ndarray], str]]


def _mod2pi(x: np.ndarray) -> np.ndarray:
    """Angle wrapped to (-π, π]."""
    return (x + PI) % (2 * PI) - PI


def _polar(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.hypot(x, y), np.arctan2(y, x)


def _lsl(x, y, phi):
    u, t = _polar(x - np.sin(phi), y - 1.0 + np.cos(phi))
    v = _mod2pi(phi - t)
    return (t >= 0) & (t <= PI) & (v >= 0) & (v <= PI), [t, u, v], "LSL"


def _lsr(x, y, phi):
    u1, t1 = _polar(x + np.sin(phi), y - 1.0 - np.cos(phi))
    u1 = u1 ** 2
    ok = u1 >= 4.0
    u = np.sqrt(np.maximum(u1 - 4.0, 0.0))
    t = _mod2pi(t1 + np.arctan2(2.0, u))
    v = _mod2pi(t - phi)
    return ok & (t >= 0) & (v >= 0), [t, u, v], "LSR"


def _ccc_base(x, y, phi):
    u1, theta = _polar(x - np.sin(phi), y - 1.0 + np.cos(phi))
    return u1, theta, u1 <= 4.0


def _lrl_a(x, y, phi):  # L+ R- L+
    u1, theta, ok = _ccc_base(x, y, phi)
    a = np.arccos(np.clip(0.25 * u1, -1, 1))
    t = _mod2pi(a + theta + PI / 2)
    u = _mod2pi(PI - 2 * a)
    v = _mod2pi(phi - t - u)
    return ok & (t >= 0) & (u >= 0) & (v >= 0), [t, -u, v], "LRL"


def _lrl_b(x, y, phi):  # L+ R- L-
    u1, theta, ok = _ccc_base(x, y, phi)
    a = np.arccos(np.clip(0.25 * u1, -1, 1))
    t = _mod2pi(a + theta + PI / 2)
    u = _mod2pi(PI - 2 * a)
    v = _mod2pi(-phi + t + u)
    return ok & (t >= 0) & (u >= 0) & (v >= 0), [t, -u, -v], "LRL"


def _lrl_c(x, y, phi):  # L+ R+ L-
    u1, theta, ok = _ccc_base(x, y, phi)
    u = np.arccos(np.clip(1 - u1 ** 2 * 0.125, -1, 1))
    a = np.arcsin(np.clip(2 * np.sin(u) / np.maximum(u1, 1e-12), -1, 1))
    t = _mod2pi(-a + theta + PI / 2)
    v = _mod2pi(t - u - phi)
    return ok & (t >= 0) & (u >= 0) & (v >= 0), [t, u, -v], "LRL"


def _cc4_base(x, y, phi):
    return _polar(x + np.sin(phi), y - 1.0 - np.cos(phi))


def _lrlr_a(x, y, phi):  # L+ R+ L- R-
    u1, theta = _cc4_base(x, y, phi)
    a = np.arccos(np.clip((u1 + 2) * 0.25, -1, 1))
    t = _mod2pi(theta + a + PI / 2)
    u = _mod2pi(a)
    v = _mod2pi(phi - t + 2 * u)
    return (u1 <= 2) & (t >= 0) & (u >= 0) & (v >= 0), [t, u, -u, -v], "LRLR"


def _lrlr_b(x, y, phi):  # L+ R- L- R+
    u1, theta = _cc4_base(x, y, phi)
    u2 = (20 - u1 ** 2) / 16
    u = np.arccos(np.clip(u2, -1, 1))
    a = np.arcsin(np.clip(2 * np.sin(u) / np.maximum(u1, 1e-12), -1, 1))
    t = _mod2pi(theta + a + PI / 2)
    v = _mod2pi(t - phi)
    return (u2 >= 0) & (u2 <= 1) & (t >= 0) & (v >= 0), [t, -u, -u, v], "LRLR"


def _lrsl(x, y, phi):  # L+ R-(π/2) S- L-
    u1, theta, _ = _ccc_base(x, y, phi)
    r = np.sqrt(np.maximum(u1 ** 2 - 4, 0.0))
    u = r - 2
    t = _mod2pi(theta + np.arctan2(2, r) + PI / 2)
    v = _mod2pi(t - phi + PI / 2)
    ok = (u1 >= 2.0) & (t >= 0) & (v >= 0) & (u >= 0)
    return ok, [t, np.full_like(t, -PI / 2), -u, -v], "LRSL"


def _lsrl(x, y, phi):  # L+ S+ R+(π/2) L-
    u1, theta, _ = _ccc_base(x, y, phi)
    r = np.sqrt(np.maximum(u1 ** 2 - 4, 0.0))
    u = r - 2
    t = _mod2pi(theta - np.arctan2(r, 2) + PI / 2)
    v = _mod2pi(t - phi - PI / 2)
    ok = (u1 >= 2.0) & (t >= 0) & (v >= 0) & (u >= 0)
    return ok, [t, u, np.full_like(t, PI / 2), -v], "LSRL"


def _lrsr(x, y, phi):  # L+ R-(π/2) S- R-
    u1, theta = _cc4_base(x, y, phi)
    t = _mod2pi(theta + PI / 2)
    u = u1 - 2
    v = _mod2pi(phi - t - PI / 2)
    ok = (u1 >= 2.0) & (t >= 0) & (v >= 0) & (u >= 0)
    return ok, [t, np.full_like(t, -PI / 2), -u, -v], "LRSR"


def _lslr(x, y, phi):  # L+ S+ L+(π/2) R-
    u1, theta = _cc4_base(x, y, phi)
    t = _mod2pi(theta)
    u = u1 - 2
    v = _mod2pi(phi - t - PI / 2)
    ok = (u1 >= 2.0) & (t >= 0) & (v >= 0) & (u >= 0)
    return ok, [t, u, np.full_like(t, PI / 2), -v], "LSLR"


def _lrslr(x, y, phi):  # L+ R-(π/2) S- L-(π/2) R+
    u1, theta = _cc4_base(x, y, phi)
    r = np.sqrt(np.maximum(u1 ** 2 - 4, 0.0))
    u = r - 4
    t = _mod2pi(theta + np.arctan2(2, r) + PI / 2)
    v = _mod2pi(t - phi)
    ok = (u1 >= 4.0) & (t >= 0) & (v >= 0) & (u >= 0)
    h = np.full_like(t, -PI / 2)
    return ok, [t, h, -u, h, v], "LRSLR"


FAMILIES: tuple[Family, ...] = (_lsl, _lsr, _lrl_a, _lrl_b, _lrl_c, _lrlr_a, _lrlr_b, _lrsl, _lsrl,
                                _lrsr, _lslr, _lrslr)
_SWAP = str.maketrans("LR", "RL")


def _candidates(x: np.ndarray, y: np.ndarray, phi: np.ndarray):
    """Yield (ok mask, signed segment lengths (n, k), word) for all 48 words, unit radius."""
    for fam in FAMILIES:
        for flip, refl in ((False, False), (True, False), (False, True), (True, True)):
            xs = -x if flip else x
            ys = -y if refl else y
            ps = -phi if flip != refl else phi
            ok, segs, word = fam(xs, ys, ps)
            seg = np.stack([np.broadcast_to(s, x.shape) for s in segs], axis=-1)
            if flip:
                seg = -seg
            yield ok, seg, word.translate(_SWAP) if refl else word


def _relative(start: np.ndarray, goal: np.ndarray, radius_m: float):
    """Goal in the start's frame, scaled to unit turning radius; start/goal are (..., 3)."""
    dx, dy = goal[..., 0] - start[..., 0], goal[..., 1] - start[..., 1]
    c, s = np.cos(start[..., 2]), np.sin(start[..., 2])
    return ((c * dx + s * dy) / radius_m, (-s * dx + c * dy) / radius_m,
            _mod2pi(goal[..., 2] - start[..., 2]))


def shortest_lengths(start: np.ndarray, goal: np.ndarray, radius_m: float) -> np.ndarray:
    """Length [m] of the shortest Reeds–Shepp path for each row of (n, 3) starts / goals."""
    x, y, phi = _relative(np.atleast_2d(start), np.atleast_2d(goal), radius_m)
    best = np.full(x.shape, np.inf)
    for ok, seg, _ in _candidates(x, y, phi):
        best = np.where(ok, np.minimum(best, np.abs(seg).sum(axis=-1)), best)
    return best * radius_m


@dataclass(frozen=True)
class RsPath:
    """One Reeds–Shepp path: a word of 'L', 'S', 'R' and signed segment lengths [m] (<0 reverse)."""

    word: str
    lengths_m: tuple[float, ...]

    @property
    def length_m(self) -> float:
        return float(sum(abs(s) for s in self.lengths_m))


def sample(start: tuple[float, float, float], path: RsPath, radius_m: float,
           step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses (m, 3), curvature [1/m] and direction (±1) at most ``step_m`` apart along the path.

    Each row's curvature and direction are those of the motion that *arrives* at the pose (row 0
    takes the first segment's). Arcs are integrated in closed form.
    """
    poses, kappa, dirs = [np.asarray(start, dtype=float)], [], []
    for ch, seg in zip(path.word, path.lengths_m, strict=True):
        if abs(seg) < 1e-9:
            continue
        k = {"L": 1.0, "S": 0.0, "R": -1.0}[ch] / radius_m
        n = max(1, int(np.ceil(abs(seg) / step_m)))
        x0, y0, th0 = poses[-1] if poses[-1].ndim == 1 else poses[-1][-1]
        s = np.linspace(0.0, seg, n + 1)[1:]
        poses.append(arc(x0, y0, th0, s, k))
        kappa += [k] * n
        dirs += [1.0 if seg > 0 else -1.0] * n
    out = np.vstack([p.reshape(-1, 3) for p in poses])
    kappa = [kappa[0] if kappa else 0.0] + kappa
    dirs = [dirs[0] if dirs else 1.0] + dirs
    return out, np.asarray(kappa), np.asarray(dirs)


def arc(x0: float, y0: float, th0: float, s: np.ndarray, kappa: float) -> np.ndarray:
    """Poses (n, 3) after signed arc lengths ``s`` [m] at constant curvature from (x0, y0, th0)."""
    th = th0 + kappa * s
    if abs(kappa) < 1e-12:
        return np.column_stack([x0 + s * np.cos(th0), y0 + s * np.sin(th0), th])
    return np.column_stack([x0 + (np.sin(th) - np.sin(th0)) / kappa,
                            y0 - (np.cos(th) - np.cos(th0)) / kappa, th])


def paths(start: tuple[float, float, float], goal: tuple[float, float, float], radius_m: float,
          max_paths: int = 48, tol_m: float = 1e-6) -> list[RsPath]:
    """All valid Reeds–Shepp paths from ``start`` to ``goal``, shortest first (each verified)."""
    x, y, phi = (float(v) for v in _relative(np.asarray(start, float), np.asarray(goal, float), radius_m))
    found: list[RsPath] = []
    for fam in FAMILIES:  # scalar evaluation: one pose, so no array overhead
        for flip, refl in ((False, False), (True, False), (False, True), (True, True)):
            ok, segs, word = fam(-x if flip else x, -y if refl else y, -phi if flip != refl else phi)
            if not ok:
                continue
            lengths = tuple(float(v) * radius_m * (-1.0 if flip else 1.0) for v in segs)
            if all(np.isfinite(lengths)):
                found.append(RsPath(word.translate(_SWAP) if refl else word, lengths))
    found.sort(key=lambda p: p.length_m)
    good = []
    for p in found:
        end = _end(start, p, radius_m)
        dth = float(_mod2pi(np.asarray(end[2] - goal[2])))
        if np.hypot(end[0] - goal[0], end[1] - goal[1]) < max(tol_m, 1e-6 * radius_m) and abs(dth) < 1e-6:
            good.append(p)
            if len(good) >= max_paths:
                break
    return good


def _end(start: tuple[float, float, float], path: RsPath, radius_m: float) -> tuple[float, float, float]:
    x, y, th = (float(v) for v in start)
    for ch, seg in zip(path.word, path.lengths_m, strict=True):
        k = {"L": 1.0, "S": 0.0, "R": -1.0}[ch] / radius_m
        if k == 0.0:
            x, y = x + seg * math.cos(th), y + seg * math.sin(th)
        else:
            th1 = th + k * seg
            x, y = x + (math.sin(th1) - math.sin(th)) / k, y - (math.cos(th1) - math.cos(th)) / k
            th = th1
    return x, y, th
