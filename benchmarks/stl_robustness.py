"""Offline space robustness: corridor.stl vs RTAMT 0.4.10 on the same data, same process.

    python benchmarks/stl_robustness.py [--dt 0.1] [--sizes 100000 1000000] [--rtamt-budget 60]

Formula ``G[0,10]((x > 0) -> F[0,5](y > 0.5)) & G[0,100](z < 3)`` over random signals. RTAMT is first
timed on a small probe; a size whose linearly extrapolated RTAMT time exceeds the budget is skipped
for RTAMT (and said so). corridor times are the best of 3 calls (the first call pays page faults),
RTAMT runs once. Also checks that both give the same robustness trace. Prints; not a test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import rtamt

from corridor.stl import space_robustness, time_robustness

FORMULA = "G[0,10]((x > 0) -> F[0,5](y > 0.5)) & G[0,100](z < 3)"
RTAMT_FORMULA = "out = (always[0:10]((x > 0) implies (eventually[0:5](y > 0.5)))) and (always[0:100](z < 3))"


def make_signals(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    return {"x": rng.normal(size=n), "y": rng.normal(size=n), "z": 2.0 + rng.normal(size=n)}


def run_rtamt(signals: dict[str, np.ndarray], dt: float) -> np.ndarray:
    spec = rtamt.StlDiscreteTimeSpecification()
    spec.set_sampling_period(dt, "s", 0.1)
    for name in ("x", "y", "z", "out"):
        spec.declare_var(name, "float")
    spec.spec = RTAMT_FORMULA
    spec.parse()
    n = signals["x"].size
    data = {"time": (dt * np.arange(n)).tolist(), **{k: v.tolist() for k, v in signals.items()}}
    return np.array([value for _, value in spec.evaluate(data)])


def timed(fn, *args, repeats: int = 1) -> tuple[float, object]:
    """Best wall time [s] over ``repeats`` calls, and the result."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - start)
    return best, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dt", type=float, default=0.1, help="sample period [s]")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--rtamt-budget", type=float, default=60.0, help="[s] skip RTAMT above this")
    args = parser.parse_args()
    rng = np.random.default_rng(0)

    probe_n = 10_000
    probe_s, _ = timed(run_rtamt, make_signals(rng, probe_n), args.dt)
    print(f"formula: {FORMULA}   dt = {args.dt} s   (RTAMT probe: {probe_n} samples in {probe_s:.2f} s)")
    print(f"{'samples':>9} {'corridor [s]':>13} {'+time rob [s]':>14} {'RTAMT [s]':>10} {'ratio':>8}  agree")
    for n in args.sizes:
        signals = make_signals(rng, n)
        ours_s, ours = timed(space_robustness, FORMULA, signals, args.dt, repeats=3)
        theta_s, _ = timed(time_robustness, FORMULA, signals, args.dt, repeats=3)
        estimate_s = probe_s * n / probe_n
        if estimate_s > args.rtamt_budget:
            print(f"{n:>9} {ours_s:>13.3f} {theta_s:>14.3f} {'skipped':>10} {'-':>8}  "
                  f"(RTAMT estimated {estimate_s:.0f} s > budget {args.rtamt_budget:.0f} s)")
            continue
        theirs_s, theirs = timed(run_rtamt, signals, args.dt)
        agree = bool(np.allclose(ours, theirs, rtol=0, atol=1e-9))
        print(f"{n:>9} {ours_s:>13.3f} {theta_s:>14.3f} {theirs_s:>10.2f} {theirs_s / ours_s:>7.0f}x  {agree}")


if __name__ == "__main__":
    main()
