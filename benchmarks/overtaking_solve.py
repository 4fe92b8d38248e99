"""Overtaking MPC: solve time p50/p95 and re-plans, event-triggered versus re-planning every period.

Runs the pure-Python overtaking world (no SUMO) for a set of seeds with both re-planning schemes and
prints, per scheme: success rate, collisions, the safety spec's minimum space robustness, solve time
p50/p95 (all IPOPT solves, including decision solves), re-plans per run; then the re-plan ratio
event / every-step and whether p95 is below the controller period (real time).

    python benchmarks/overtaking_solve.py --seeds 10 --milp 10

``--milp N`` adds the comparison of the smooth-robustness NLP (IPOPT) with the big-M mixed-integer
encoding (HiGHS) on N random go/no-go pass problems.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from corridor.controllers.overtaking.controller import OvertakingParams
from corridor.controllers.overtaking.mpc import (
    FAR_M,
    MpcProblem,
    OvertakingMilp,
    OvertakingMpc,
    cached_mpc,
    pass_guess,
)
from corridor.controllers.overtaking.sim import OvertakingRun, OvertakingWorldParams, run_overtaking


def _batch(params: OvertakingParams, world: OvertakingWorldParams, seeds: range) -> list[OvertakingRun]:
    return [run_overtaking(seed, params, world) for seed in seeds]


def _row(name: str, runs: list[OvertakingRun]) -> dict[str, float]:
    st = np.concatenate([r.solve_times_s for r in runs]) * 1e3
    dec = np.concatenate([r.decision_solves for r in runs]).astype(bool)
    row = {
        "passed": np.mean([r.outcome == "passed" for r in runs]),
        "aborted": np.mean([r.outcome == "aborted" for r in runs]),
        "collisions": float(sum(r.collided for r in runs)),
        "min_space_rob_m": min(r.space_robustness_m for r in runs),
        "p50_ms": float(np.percentile(st, 50)),
        "p95_ms": float(np.percentile(st, 95)),
        "track_p50_ms": float(np.percentile(st[~dec], 50)),
        "track_p95_ms": float(np.percentile(st[~dec], 95)),
        "decide_p95_ms": float(np.percentile(st[dec], 95)) if dec.any() else float("nan"),
        "replans_per_run": float(np.mean([r.replans for r in runs])),
        "periods_per_run": float(np.mean([r.steps for r in runs])),
    }
    print(f"{name:<11} passed {row['passed']:.0%}  aborted {row['aborted']:.0%}  collisions {row['collisions']:.0f}  "
          f"min space rob {row['min_space_rob_m']:+.2f} m  solve p50 {row['p50_ms']:.1f} ms  p95 {row['p95_ms']:.1f} ms  "
          f"re-plans/run {row['replans_per_run']:.1f} of {row['periods_per_run']:.0f} periods")
    reasons: dict[str, int] = {}
    for r in runs:
        for k, v in r.replan_reasons.items():
            reasons[k] = reasons.get(k, 0) + v
    print(f"{'':<11} re-plan triggers: " + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())))
    print(f"{'':<11} tracking solves p50 {row['track_p50_ms']:.1f} ms  p95 {row['track_p95_ms']:.1f} ms; "
          f"go/no-go decision solves p95 {row['decide_p95_ms']:.1f} ms")
    return row


def _decision_problem(rng: np.random.Generator, mpc: OvertakingMpc) -> MpcProblem:
    """A random go/no-go pass problem: slow lead ahead, one to three oncoming cars at random gaps."""
    p, n = mpc.p, mpc.n
    ts = np.arange(n + 1) * p.dt_s
    v_lead = rng.uniform(13.0, 19.0)
    x0 = np.array([0.0, 0.0, 0.0, v_lead])
    lead = 0.5 * mpc.ego.wheelbase_m + 4.5 + rng.uniform(15.0, 35.0) + v_lead * ts
    m = p.max_oncoming
    onc, onc_v = np.full((m, n + 1), FAR_M), np.zeros(m)
    first = rng.uniform(200.0, 700.0)
    for j in range(int(rng.integers(1, m + 1))):
        onc_v[j] = -rng.uniform(18.0, 26.0)
        onc[j] = first + 400.0 * j + onc_v[j] * ts
    mask = np.zeros(n + 1)
    mask[-1] = 1.0
    return MpcProblem(x0, np.zeros(2), lead, onc, onc_v, p.speed_limit_mps, 0.0, mask)


def compare_milp(count: int, seed: int = 0) -> None:
    """Smooth-robustness IPOPT vs big-M MILP (HiGHS) on the same random go/no-go pass problems."""
    base = OvertakingParams()
    mpc = cached_mpc(base.mpc, base.ego, base.road)
    milp = OvertakingMilp(mpc)
    rng = np.random.default_rng(seed)
    t_nlp, t_milp, agree, rho_milp = [], [], 0, []
    for _ in range(count):
        prob = _decision_problem(rng, mpc)
        a = mpc.solve(prob, *pass_guess(prob, mpc), decision=True)
        b = milp.solve(prob)
        t_nlp.append(a.solve_time_s * 1e3)
        t_milp.append(b.solve_time_s * 1e3)
        agree += a.ok == b.ok
        if b.ok:
            rho_milp.append(b.robustness_m)
    print(f"smooth IPOPT  solve p50 {np.percentile(t_nlp, 50):.0f} ms  p95 {np.percentile(t_nlp, 95):.0f} ms")
    print(f"big-M MILP    solve p50 {np.percentile(t_milp, 50):.0f} ms  p95 {np.percentile(t_milp, 95):.0f} ms "
          f"(HiGHS, time limit {milp.time_limit_s:.0f} s; plans replayed in the nonlinear model)")
    print(f"same go/no-go verdict on {agree}/{count} problems; MILP ratio p50 {np.median(t_milp) / np.median(t_nlp):.1f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=30.0, help="[s] simulated time per run")
    ap.add_argument("--milp", type=int, default=0, help="also compare with the big-M MILP on this many problems")
    args = ap.parse_args()
    world = OvertakingWorldParams(duration_s=args.duration)
    seeds = range(args.seeds)
    base = OvertakingParams()
    t0 = time.perf_counter()
    ev = _row("event", _batch(base, world, seeds))
    every = _row("every-step", _batch(base.model_copy(update={"replan": "every_step"}), world, seeds))
    ratio = ev["replans_per_run"] / every["replans_per_run"]
    period_ms = base.period_s * 1e3
    print(f"re-plans event/every-step = {ratio:.2f}  (saves {1 - ratio:.0%} of the solves)")
    print(f"p95 below the controller period ({period_ms:.0f} ms): event {ev['p95_ms'] < period_ms}, "
          f"every-step {every['p95_ms'] < period_ms}   [wall {time.perf_counter() - t0:.0f} s, {args.seeds} seeds]")
    if args.milp > 0:
        compare_milp(args.milp)


if __name__ == "__main__":
    main()
