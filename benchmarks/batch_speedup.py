"""Batch speed-up, 2 workers vs 1, on many short runs: the fork-server executor (a pre-imported
``python -m corridor.worker --serve`` per worker slot forks each run) against the previous one (a
fresh ``python -m corridor.worker`` process per run), all four batches in the same run.

Prints, per executor, the batch wall time with 1 and 2 workers and their ratio (the speed-up), the
per-run overhead (batch wall time with 1 worker minus the runs' own ``wall_s``, per run: process
start, imports, row transfer and writing), the CPU time per run of the whole batch (parent and all
workers, from ``getrusage``: what does not depend much on the machine's load) with 1 and 2 workers,
and the 2-vs-1 speed-up those CPU times predict on 2 idle cores.

    python benchmarks/batch_speedup.py [--runs 16] [--repeat 1] [--scenario scenarios/hegyi_benchmark.yaml]
        [--set duration=600] [--variant none] [--quick]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from corridor.batch import expand, run_batch
from corridor.results import ResultStore
from corridor.scenario import load

ROOT = Path(__file__).resolve().parents[1]


def _cpu_s() -> float:
    """CPU time of this process and of all its reaped descendants [s]."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def one_batch(path: str, sets: list[str], variant: str, runs: int, workers: int, fork_server: bool) -> dict[str, Any]:
    """Run one batch into a scratch folder; wall and CPU time, and the runs' own wall times."""
    sc, raw = load(path, sets)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="corridor-bench-") as tmp:
        plan = expand(sc, raw, path, runs=runs, variants=[variant], out_dir=tmp)
        c0, t0 = _cpu_s(), time.perf_counter()
        run_batch(plan, ResultStore(tmp), workers=workers, progress=False, on_row=rows.append,
                  fork_server=fork_server)
        wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    bad = [r["run_id"] for r in rows if r["status"] != "ok"]
    if bad:
        raise SystemExit(f"batch_speedup: runs failed: {', '.join(bad)}")
    return {"wall_s": wall, "cpu_s": cpu, "run_wall_s": sum(r["wall_s"] for r in rows), "runs": len(rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "hegyi_benchmark.yaml"))
    ap.add_argument("--set", dest="sets", action="append", default=None, help="scenario override a.b=c")
    ap.add_argument("--variant", default="none")
    ap.add_argument("--runs", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=1, help="batches per configuration (medians are printed)")
    ap.add_argument("--quick", action="store_true", help="8 runs (for make bench)")
    args = ap.parse_args()
    sets = args.sets if args.sets is not None else ["duration=600"]
    runs = 8 if args.quick else args.runs
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    configs = [(fork, w) for fork in (True, False) for w in (1, 2)]
    res: dict[tuple[bool, int], list[dict[str, Any]]] = {c: [] for c in configs}
    load0 = os.getloadavg()[0]
    for _ in range(args.repeat):  # interleaved: every configuration sees the same spread of load
        for fork, w in configs:
            res[(fork, w)].append(one_batch(args.scenario, sets, args.variant, runs, w, fork))
    load1 = os.getloadavg()[0]

    def med(fork: bool, w: int, key: str) -> float:
        return statistics.median(r[key] for r in res[(fork, w)])

    print(f"{Path(args.scenario).name} [{args.variant}] {' '.join(sets)}: {runs} runs per batch, "
          f"{args.repeat} batch(es) per configuration, {os.cpu_count()} CPUs, load average {load0:.1f} -> {load1:.1f}")
    print(f"{'executor':>12}{'1 worker [s]':>14}{'2 workers [s]':>15}{'speed-up':>10}{'overhead/run [s]':>18}"
          f"{'cpu/run 1w [s]':>16}{'cpu/run 2w [s]':>16}{'idle est.':>11}")
    for fork, name in ((True, "fork server"), (False, "spawn/run")):
        t1, t2 = med(fork, 1, "wall_s"), med(fork, 2, "wall_s")
        overhead = (t1 - med(fork, 1, "run_wall_s")) / runs
        cpu1, cpu2 = med(fork, 1, "cpu_s"), med(fork, 2, "cpu_s")
        # idle 2-core estimate: one worker runs all CPU in series; two share it, except what each
        # worker process pays once (a fork server's imports: cpu2 - cpu1, the second server's share)
        once = max(cpu2 - cpu1, 0.0) if fork else 0.0
        idle = cpu1 / (once + (cpu1 - once) / 2)
        print(f"{name:>12}{t1:>14.2f}{t2:>15.2f}{t1 / t2:>10.2f}{overhead:>18.3f}{cpu1 / runs:>16.3f}"
              f"{cpu2 / runs:>16.3f}{idle:>11.2f}")
    for w in (1, 2):
        print(f"{w} worker(s): fork server / spawn per run, batch wall time {med(True, w, 'wall_s') / med(False, w, 'wall_s'):.2f}")
    print("(a speed-up below 2 on a loaded machine is the load's share of the cores: compare the ratios "
          "and the CPU per run, which the load does not change much; 'idle est.' is the 2-vs-1 speed-up "
          "these CPU times give on 2 idle cores, each fork server paying its first run's imports once)")


if __name__ == "__main__":
    main()
