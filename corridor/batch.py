"""Batches: expand seeds × sweep variants × randomize draws into runs, execute them on an executor,
write each finished run at once, compact into ``runs.parquet``.

Executors: ``local`` (a process pool; libsumo allows one simulation per process) and ``ray``
(``pip install corridor[ray]``).  Both call ``corridor.run.execute`` and give identical rows.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

import numpy as np

from corridor.engine import stable_key
from corridor.errors import CorridorError
from corridor.results import ResultStore
from corridor.run import RunSpec, execute
from corridor.scenario import Scenario


def draws_for(sc: Scenario, seed: int) -> dict[str, Any]:
    """Randomize draws depend on the seed only, so every variant sees the same draws (common random
    numbers make variant comparisons sharper)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stable_key("randomize"),)))
    return {path: dist.draw(rng) for path, dist in sorted(sc.randomize.items())}


def expand(sc: Scenario, raw: dict[str, Any], source: str, runs: int, seed: int | None = None,
           out_dir: str | None = None, variants: list[str] | None = None) -> list[RunSpec]:
    base_seed = sc.seed if seed is None else seed
    names = list(sc.sweep)
    if variants:
        unknown = [v for v in variants if v not in sc.sweep]
        if unknown:
            raise CorridorError(f"{source}: --variant {unknown[0]!r}: not in sweep ({', '.join(names)})")
        names = [v for v in names if v in variants]
    specs = []
    for i in range(runs):
        s = base_seed + i
        draws = draws_for(sc, s)
        for v in names:
            specs.append(RunSpec(run_id=f"{v}-s{s}", scenario=sc.name, source=source, variant=v, seed=s,
                                 base=raw, overrides={**sc.sweep[v], **draws}, draws=draws,
                                 out_dir=out_dir))
    return specs


# Math-library thread pools in every worker process: one thread.  A run is single-threaded work
# (SUMO, JSBSim, small dense algebra, IPOPT/MUMPS on a few thousand variables) and the batch already
# fills the cores with processes; OpenBLAS/OpenMP threads on top oversubscribe them and spin (the
# beltway MPC's p95 solve time: 3.98 s -> 1.53 s on this 2-core machine).  A value the user set wins.
WORKER_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _local(specs: list[RunSpec], workers: int) -> Iterator[dict[str, Any]]:
    for var in WORKER_THREAD_ENV:  # spawned workers inherit the environment and read it at import
        os.environ.setdefault(var, "1")
    ctx = mp.get_context("spawn")  # no inherited libsumo/CasADi state; same behaviour on every OS
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=1) as pool:
        pending = {pool.submit(execute, s): s for s in specs}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                spec = pending.pop(fut)
                try:
                    yield fut.result()
                except Exception as exc:  # the worker process died (e.g. a segfault in a library)
                    yield {"run_id": spec.run_id, "scenario": spec.scenario, "variant": spec.variant,
                           "seed": spec.seed, "status": "error", "error": f"worker died: {exc}"}


def _ray(specs: list[RunSpec], address: str | None) -> Iterator[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise CorridorError("--executor ray needs the extra: pip install 'corridor[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(max_calls=1)(execute)  # one simulation per worker process, like the pool
    pending = [remote.remote(s) for s in specs]
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        yield ray.get(done[0])


def run_batch(specs: list[RunSpec], store: ResultStore, executor: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True,
              on_row: Callable[[dict[str, Any]], None] | None = None) -> None:
    """Execute runs not yet in the store; each finished row is written at once."""
    todo = [s for s in specs if s.run_id not in store.finished()]
    bar = _progress(len(specs), len(specs) - len(todo), progress)
    try:
        if todo:
            rows = _ray(todo, address) if executor == "ray" else _local(todo, max(1, workers))
            for row in rows:
                store.write(row)
                bar.update(1)
                bar.set_postfix_str(f"{row['run_id']} {row['status']}")
                if on_row:
                    on_row(row)
    finally:
        bar.close()
    store.compact([s.run_id for s in specs])


def _progress(total: int, initial: int, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="runs", unit="run", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)
