"""Per-step cost of the control-tube QP: solver time and whole step (assembly + solve), p50/p95.

    python benchmarks/avoidance_solve.py [--solver qpoases|osqp] [--duration 60]

Runs the head-on pair (1 intruder per QP) and the 8-UAV swap (up to 7 intruders per QP) in the
point-mass harness and prints the percentiles over every QP solved (``uncon``: steps whose
unconstrained optimum was feasible, taken without a solver call). Not run by CI.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from corridor.controllers.uav.control_tube import ControlTubeAvoidance, ControlTubeParams
from corridor.controllers.uav.models import AvoidanceObservation, PointMassParams, encounter, fly


class _Timed(ControlTubeAvoidance):
    """Records the wall time of the whole step next to the solver time the controller records."""

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.step_times_s: list[float] = []

    def step(self, obs: AvoidanceObservation):  # noqa: ANN201 - same return type as the parent
        t0 = time.perf_counter()
        out = super().step(obs)
        self.step_times_s.append(time.perf_counter() - t0)
        return out


def _case(name: str, params: ControlTubeParams, duration_s: float) -> dict[str, float]:
    x0, goals = encounter(name)
    ctrls = [_Timed(params) for _ in x0]
    fly(ctrls, x0, goals, PointMassParams(), duration_s, dt_s=0.05, control_period_s=params.period_s)
    solve = np.concatenate([c.solve_times_s for c in ctrls]) * 1e3
    step = np.concatenate([c.step_times_s for c in ctrls]) * 1e3
    return {
        "qps": float(len(solve)),
        "solve_p50_ms": float(np.percentile(solve, 50)),
        "solve_p95_ms": float(np.percentile(solve, 95)),
        "step_p50_ms": float(np.percentile(step, 50)),
        "step_p95_ms": float(np.percentile(step, 95)),
        "infeasible": float(sum(c.infeasible_steps for c in ctrls)),
        "unconstrained": float(sum(c.unconstrained_steps for c in ctrls)),  # steps without a solver call
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", default="qpoases", choices=["qpoases", "osqp"])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per case")
    args = ap.parse_args()
    cases = {
        "head_on (1 intruder)": ("head_on", ControlTubeParams(solver=args.solver)),
        "swap x8 (<=7 intruders)": (
            "swap",
            ControlTubeParams(solver=args.solver, uav_accel_mps2=0.5, period_s=0.2),
        ),
    }
    print(f"solver={args.solver}  horizon={ControlTubeParams().n_steps} x {ControlTubeParams().step_s} s")
    header = (f"{'case':26s} {'QPs':>6s} {'solve p50':>10s} {'p95':>8s} {'step p50':>10s} {'p95':>8s} {'infeas':>7s}"
              f" {'uncon':>6s}")
    print(header)
    for label, (name, params) in cases.items():
        r = _case(name, params, args.duration)
        print(
            f"{label:26s} {r['qps']:6.0f} {r['solve_p50_ms']:8.2f}ms {r['solve_p95_ms']:6.2f}ms "
            f"{r['step_p50_ms']:8.2f}ms {r['step_p95_ms']:6.2f}ms {r['infeasible']:7.0f} {r['unconstrained']:6.0f}"
        )


if __name__ == "__main__":
    main()
