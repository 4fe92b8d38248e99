"""TPCAP case files: one line of comma-separated numbers (start pose, goal pose, obstacle polygons)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corridor.errors import CorridorError, clip

MAX_CASE_BYTES = 16_000_000  # bound on a case file's size [bytes]
MAX_OBSTACLES = 20_000  # bound on the number of obstacle polygons
MAX_VERTICES = 200_000  # bound on the number of vertices of all obstacles


class CaseError(CorridorError, ValueError):
    """A case file that is missing, malformed or over a size bound (one-line message)."""


@dataclass(frozen=True, eq=False)
class Case:
    start: tuple[float, float, float]  # rear-axle centre x [m], y [m], heading [rad]
    goal: tuple[float, float, float]
    obstacles: tuple[np.ndarray, ...]  # each (k, 2) [m]


def parse_case(text: str, name: str = "case") -> Case:
    """Parse the TPCAP line format: x0,y0,θ0, xf,yf,θf, N, k_1..k_N, then the vertices."""
    toks = [tok for tok in text.replace("\n", ",").split(",") if tok.strip()]
    try:
        v = [float(tok) for tok in toks]
    except ValueError:
        bad = next(tok for tok in toks if not _is_number(tok))
        raise CaseError(f"{name}: not a list of numbers (found {clip(bad.strip())})") from None
    if len(v) < 7 or not all(math.isfinite(x) for x in v):
        raise CaseError(f"{name}: expected at least 7 finite numbers, got {len(v)}")
    n = v[6]
    if n < 0 or n != int(n) or 7 + int(n) > len(v):
        raise CaseError(f"{name}: bad obstacle count {n:g}")
    if n > MAX_OBSTACLES:
        raise CaseError(f"{name}: {n:.0f} obstacles exceed the bound of {MAX_OBSTACLES} (MAX_OBSTACLES)")
    counts = v[7:7 + int(n)]
    if any(k < 3 or k != int(k) for k in counts):
        raise CaseError(f"{name}: every obstacle needs an integer number (>= 3) of vertices")
    if sum(counts) > MAX_VERTICES:
        raise CaseError(f"{name}: {sum(counts):.0f} vertices exceed the bound of {MAX_VERTICES} (MAX_VERTICES)")
    coords = v[7 + int(n):]
    if len(coords) != 2 * int(sum(counts)):
        raise CaseError(f"{name}: expected {2 * int(sum(counts))} vertex coordinates, got {len(coords)}")
    polys, i = [], 0
    for k in counts:
        polys.append(np.asarray(coords[i:i + 2 * int(k)], dtype=float).reshape(-1, 2))
        i += 2 * int(k)
    return Case(start=(v[0], v[1], v[2]), goal=(v[3], v[4], v[5]), obstacles=tuple(polys))


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def read_case(path: str | Path) -> Case:
    """The case in file ``path``; CaseError (one line) if unreadable, malformed or larger than
    `MAX_CASE_BYTES` (read up to the bound only, so ``/dev/zero`` is refused, not read forever)."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_CASE_BYTES + 1)
        if len(raw) > MAX_CASE_BYTES:
            raise CaseError(f"{p}: larger than the bound of {MAX_CASE_BYTES / 1e6:g} MB (MAX_CASE_BYTES)")
        text = raw.decode()
    except (OSError, UnicodeDecodeError) as exc:
        raise CaseError(f"{p}: cannot read ({exc.__class__.__name__}: {exc})") from None
    return parse_case(text, str(p))


def format_case(case: Case) -> str:
    """The TPCAP line of a case (inverse of `parse_case`)."""
    vals = [*case.start, *case.goal, len(case.obstacles), *(len(p) for p in case.obstacles)]
    vals += [c for p in case.obstacles for c in np.asarray(p).ravel()]
    return ",".join(repr(float(x)) if not float(x).is_integer() or abs(x) > 1e6 else str(int(x))
                    for x in vals)
