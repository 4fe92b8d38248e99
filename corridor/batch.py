"""Batches: expand seeds × sweep variants × randomize draws into runs, execute them on an executor,
write each finished run at once, compact into ``runs.parquet``.

Executors: ``local`` (one process per run, at most ``workers`` at once, each forked from a
pre-imported fork server per worker slot, see ``corridor.worker``; libsumo allows one simulation per
process) and ``ray`` (``pip install -e '.[ray]'``).  Both call ``corridor.run.execute``
and give identical rows.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import wait as mp_wait
from pathlib import Path
from typing import Any, cast

import numpy as np

from corridor.engine import stable_key
from corridor.errors import CorridorError, clip
from corridor.results import ResultStore
from corridor.run import RunSpec, execute
from corridor.scenario import MAX_SEED, Scenario
from corridor.worker import FRAME, SPEC_LEN


def draw_seed(seed: int, path: str) -> np.random.SeedSequence:
    """The random stream of one randomized field: keyed by the run seed and the field's path only."""
    return np.random.SeedSequence(seed, spawn_key=(stable_key("randomize"), stable_key(path)))


def draws_for(sc: Scenario, seed: int) -> dict[str, Any]:
    """Randomize draws depend on the seed only, so every variant sees the same draws (common random
    numbers make variant comparisons sharper).  Each field draws from its own stream keyed by its
    path, so adding, removing or ``--set``-fixing one field never changes another's values."""
    return {path: dist.draw(np.random.default_rng(draw_seed(seed, path)))
            for path, dist in sorted(sc.randomize.items())}


class RunPlan(Sequence[RunSpec]):
    """The runs of a batch, seeds × variants, built lazily (``--runs 1000000000`` costs nothing up
    front).  Run ids are ``<variant>-s<seed>``; ``rank(run_id)`` gives a run's place in the batch."""

    def __init__(self, sc: Scenario, raw: dict[str, Any], source: str, runs: int, seed: int | None = None,
                 out_dir: str | None = None, variants: list[str] | None = None,
                 after: dict[str, Any] | None = None) -> None:
        self.sc, self.raw, self.source, self.runs, self.out_dir = sc, raw, source, runs, out_dir
        self.after = after or {}  # the --set values, applied again after the variant (the command line wins)
        self.base_seed = sc.seed if seed is None else seed
        if self.base_seed < 0 or self.base_seed + runs - 1 > MAX_SEED:
            raise CorridorError(f"{source}: seeds {self.base_seed}..{self.base_seed + runs - 1} (--seed, --runs) "
                                f"must lie in 0..{MAX_SEED}")
        names = list(sc.sweep)
        if variants:
            unknown = [v for v in variants if v not in sc.sweep]
            if unknown:
                raise CorridorError(f"{source}: --variant {clip(unknown[0])}: not in sweep ({', '.join(names)})")
            names = [v for v in names if v in variants]
        self.variants = names
        self._rerun: dict[str, str] = {}
        self.base_dir = str(Path(source).resolve().parent)  # files the scenario names are relative to it

    def __len__(self) -> int:
        return self.runs * len(self.variants)

    def __getitem__(self, i: int) -> RunSpec:  # type: ignore[override]
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        i %= len(self)
        s, v = self.base_seed + i // len(self.variants), self.variants[i % len(self.variants)]
        draws = draws_for(self.sc, s)
        run_id = f"{v}-s{s}"
        return RunSpec(run_id=run_id, scenario=self.sc.name, source=self.source, variant=v, seed=s,
                       base=self.raw, overrides={**self.sc.sweep[v], **draws, **self.after}, draws=draws,
                       out_dir=self.out_dir, rerun_path=self._rerun.get(run_id), base_dir=self.base_dir)

    def __iter__(self) -> Iterator[RunSpec]:
        return (self[i] for i in range(len(self)))

    def rank(self, run_id: str) -> int:
        """The index of ``run_id`` in this plan (``len(self)`` for a run that is not in it)."""
        variant, _, seed = run_id.rpartition("-s")
        if variant in self.variants and seed.isdigit():
            k = int(seed) - self.base_seed
            if 0 <= k < self.runs:
                return k * len(self.variants) + self.variants.index(variant)
        return len(self)

    def run_ids(self) -> Iterator[str]:
        return (f"{v}-s{self.base_seed + k}" for k in range(self.runs) for v in self.variants)

    def record(self, run_id: str, rerun_path: str) -> None:
        """Record run ``run_id`` for the Rerun viewer."""
        if self.rank(run_id) == len(self):
            first = ", ".join(r for r, _ in zip(self.run_ids(), range(6)))
            raise CorridorError(f"--rerun-run {clip(run_id)}: no such run; runs are {first}, ...")
        self._rerun[run_id] = rerun_path

    def recorded(self) -> list[str]:
        """The run ids to record for the Rerun viewer."""
        return list(self._rerun)


def expand(sc: Scenario, raw: dict[str, Any], source: str, runs: int, seed: int | None = None,
           out_dir: str | None = None, variants: list[str] | None = None,
           after: dict[str, Any] | None = None) -> RunPlan:
    return RunPlan(sc, raw, source, runs, seed, out_dir, variants, after)


# Math-library thread pools in every worker process: one thread.  A run is single-threaded work
# (SUMO, JSBSim, small dense algebra, IPOPT/MUMPS on a few thousand variables) and the batch already
# fills the cores with processes; OpenBLAS/OpenMP threads on top oversubscribe them and spin (the
# beltway MPC's p95 solve time: 3.98 s -> 1.53 s on this 2-core machine).  A value the user set wins.
WORKER_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass
class Worker:
    """A ``python -m corridor.worker`` process: one run (``serve=False``), or a fork server that runs
    spec after spec, each in a forked child (``serve=True``).  Rows arrive on ``fd``.

    The local executor (:func:`run_local`) drives workers without blocking; :meth:`wait_row` is the
    blocking way for a caller that drives one server by hand."""

    proc: subprocess.Popen[bytes]
    spec: RunSpec | None  # the run in progress (None: a server waiting for work)
    fd: int
    serve: bool = False
    data: bytearray = field(default_factory=bytearray)
    retiring: bool = False  # a server that said it will exit after its last frame: give it no work

    @classmethod
    def spawn(cls, serve: bool) -> Worker:
        """Start a worker process (a fork server if ``serve``) with no run yet."""
        r, w = os.pipe()
        args = [sys.executable, "-m", "corridor.worker", *(["--serve"] if serve else []), str(w), str(os.getpid())]
        try:
            proc = subprocess.Popen(args, stdin=subprocess.PIPE, pass_fds=(w,),
                                    start_new_session=True)  # own session: no terminal SIGINT
        except BaseException:
            os.close(r)
            raise
        finally:
            os.close(w)
        os.set_blocking(r, False)
        return cls(proc, None, r, serve)

    def send(self, spec: RunSpec) -> None:
        """Hand ``spec`` to the worker (to a server as a length-prefixed frame, which keeps stdin open)."""
        self.spec = spec
        assert self.proc.stdin is not None
        body = pickle.dumps(spec, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            self.proc.stdin.write(SPEC_LEN.pack(len(body)) + body if self.serve else body)
            self.proc.stdin.flush()
            if not self.serve:
                self.proc.stdin.close()
        except OSError:  # the worker died at once; its row says so
            pass

    def wait_row(self) -> tuple[int | None, dict[str, Any]]:
        """Block until a server's run ends: the exit code of the forked run and its row (an
        ``error`` row if the run died)."""
        if not self.serve or self.spec is None:
            raise ValueError("wait_row: a fork server with a run in progress only")
        os.set_blocking(self.fd, True)
        try:
            while len(self.data) < FRAME.size or len(self.data) < FRAME.size + FRAME.unpack_from(self.data)[0]:
                chunk = os.read(self.fd, 1 << 20)
                if not chunk:
                    raise RuntimeError("the fork server closed its pipe")
                self.data += chunk
        finally:
            os.set_blocking(self.fd, False)
        code = FRAME.unpack_from(self.data)[1]
        row = _take_frame(self)
        assert row is not None
        return code, row

    def kill(self) -> None:
        """Kill the worker process at once and release its pipe."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        _close_stdin(self)
        os.close(self.fd)


def _start(spec: RunSpec, serve: bool = False, w: Worker | None = None) -> Worker:
    """Give ``spec`` to the idle server ``w`` (which the caller already tracks and stops), or to a new
    worker process."""
    if w is not None:
        w.send(spec)
        return w
    w = Worker.spawn(serve)
    try:
        w.send(spec)
    except BaseException:  # e.g. Ctrl-C right now: a worker in its own session must not outlive us
        w.proc.kill()
        w.proc.wait()
        _close_stdin(w)
        os.close(w.fd)
        raise
    return w


def _died_row(spec: RunSpec, exitcode: int | None) -> dict[str, Any]:
    how = f"signal {signal.Signals(-exitcode).name}" if exitcode and exitcode < 0 else f"exit code {exitcode}"
    return {"run_id": spec.run_id, "scenario": spec.scenario, "variant": spec.variant, "seed": spec.seed,
            "status": "error", "error": f"worker process died ({how}) before returning a row"}


def _row(spec: RunSpec, data: bytes, code: int | None) -> dict[str, Any]:
    try:
        row = pickle.loads(data) if data else None
    except Exception:  # a truncated row: the worker died while writing it
        row = None
    return row if isinstance(row, dict) else _died_row(spec, code)


def _finish(w: Worker) -> dict[str, Any] | None:
    """The worker closed its end: reap it; the row of the run it still had (None if it had none)."""
    os.close(w.fd)
    code = w.proc.wait()
    if w.spec is None:
        return None
    data = bytes(w.data)
    if w.serve:  # a server that died mid-run: a whole frame cannot be left over (it would have been taken)
        data = b""
    return _row(w.spec, data, code)


def _take_frame(w: Worker) -> dict[str, Any] | None:
    """A server's finished row, once its whole frame has arrived."""
    if len(w.data) < FRAME.size:
        return None
    n, code, retiring = FRAME.unpack_from(w.data)
    if len(w.data) < FRAME.size + n:
        return None
    data = bytes(w.data[FRAME.size:FRAME.size + n])
    del w.data[:FRAME.size + n]
    assert w.spec is not None
    row, w.spec = _row(w.spec, data, code), None
    if retiring:
        w.retiring = True
        _close_stdin(w)
    return row


def run_local(specs: Iterable[RunSpec], workers: int, fork_server: bool = True,
           said: list[bool] | None = None) -> Generator[dict[str, Any], None, None]:
    """At most ``workers`` runs at once, each in a process of its own (libsumo allows one simulation
    per process): forked from a pre-imported server per worker slot (``fork_server``), or a fresh
    ``python -m corridor.worker`` per run.  A worker that dies (segfault, kill -9) costs its own row
    only; a dead server is replaced.  Workers run in sessions of their own: a terminal's Ctrl-C
    reaches only the parent, which stops them (see ``run_batch``)."""
    for var in WORKER_THREAD_ENV:  # workers inherit the environment and read it at import
        os.environ.setdefault(var, "1")
    queue = iter(specs)
    running: dict[int, Worker] = {}

    def fill() -> int:
        """Hand queued specs to idle slots; the number of busy slots."""
        busy = sum(1 for w in running.values() if w.spec is not None)
        while busy < workers and (spec := next(queue, None)) is not None:
            idle = next((w for w in running.values() if w.spec is None and not w.retiring), None)
            w = _start(spec, fork_server, idle)
            running[w.fd] = w
            busy += 1
        return busy

    try:
        while True:
            if not fill():  # nothing left to run: idle servers get end of file on stdin and exit
                for w in running.values():
                    _close_stdin(w)
            if not running:
                return
            done: list[dict[str, Any]] = []
            for fd in cast(list[int], mp_wait(list(running))):  # file descriptors in, the ready ones out
                w = running[fd]
                chunk = os.read(fd, 1 << 20)
                if chunk:
                    w.data += chunk
                    if w.serve and (row := _take_frame(w)) is not None:
                        done.append(row)
                    continue
                del running[fd]  # end of file: the worker is done (or dead)
                if (row := _finish(w)) is not None:
                    done.append(row)
            if done:
                # the freed slots get their next runs before the caller writes these rows: a worker
                # does not wait for the parent's write (with short runs that wait was ~15 % of a run)
                fill()
                yield from done
    except KeyboardInterrupt:
        _say_stopping(sum(1 for w in running.values() if w.spec is not None))  # at once, before stopping
        if said is not None:
            said.append(True)
        raise
    finally:
        _stop(running)


def _close_stdin(w: Worker) -> None:
    if w.proc.stdin is not None and not w.proc.stdin.closed:
        try:
            w.proc.stdin.close()
        except OSError:
            pass


def _say_stopping(n_running: int | None) -> None:
    which = "the" if n_running is None else str(n_running)
    print(f"\nrun_scenario: interrupted: stopping {which} runs in progress; finished runs are kept",
          file=sys.stderr, flush=True)


def _stop(running: dict[int, Worker]) -> None:
    """Terminate runs still in progress (interrupt, write failure): SIGTERM, then SIGKILL."""
    for w in running.values():
        if w.proc.poll() is None:
            w.proc.terminate()
    for w in running.values():
        try:
            w.proc.wait(3.0)
        except subprocess.TimeoutExpired:
            w.proc.kill()
            w.proc.wait()
        _close_stdin(w)
        os.close(w.fd)
    running.clear()


class _RayRunner:
    """A Ray actor that runs spec after spec in its process: the Ray form of the local executor's
    runner (``corridor.worker``), replaced after a failed run and after ``RUNS_PER_RUNNER`` runs."""

    def run(self, spec: RunSpec) -> dict[str, Any]:
        return execute(spec)


def _ray(specs: Iterable[RunSpec], address: str | None) -> Generator[dict[str, Any], None, None]:
    """One actor per CPU of the cluster, each running one spec at a time (libsumo: one simulation at
    a time per process), spec after spec, so a run pays no worker start-up and imports (Ray used to
    start a process per run: ``max_calls=1``).  As with the local runner, a failed run, a dead
    actor (its row says so) and every ``RUNS_PER_RUNNER``-th run end the actor; the next spec gets
    a fresh one.  Specs are taken from the plan as actors free up, not all submitted at once."""
    try:
        import ray
    except ImportError:
        raise CorridorError("--executor ray needs Ray: pip install -e '.[ray]' in the corridor clone") from None
    from ray.exceptions import RayActorError

    from corridor.worker import RUNS_PER_RUNNER

    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    runner = ray.remote(num_cpus=1, max_restarts=0)(_RayRunner)
    queue = iter(specs)
    busy: dict[Any, tuple[Any, RunSpec, int]] = {}  # task ref -> (actor, spec, runs it has done before)

    def give(actor: Any, done: int) -> None:
        """Hand the next spec to ``actor`` (a new one if None), or end it when none is left."""
        spec = next(queue, None)
        if spec is None:
            if actor is not None:
                ray.kill(actor)
            return
        if actor is None:
            actor, done = runner.remote(), 0
        busy[actor.run.remote(spec)] = (actor, spec, done)

    try:
        for _ in range(max(1, int(ray.cluster_resources().get("CPU", 1)))):
            give(None, 0)
        while busy:
            (ref,), _ = ray.wait(list(busy), num_returns=1)
            actor, spec, done = busy.pop(ref)
            try:
                row = ray.get(ref)
            except RayActorError as exc:
                row, actor = _died_row(spec, None), None
                row["error"] = f"Ray worker process died before returning a row ({type(exc).__name__})"
            if actor is not None and (row.get("status") != "ok" or done + 1 >= RUNS_PER_RUNNER):
                ray.kill(actor)  # a failed run's process is not trusted for the next
                actor = None
            give(actor, done + 1)
            yield row
    finally:
        for actor, _, _ in busy.values():
            ray.kill(actor)


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C during a batch: finished rows are kept and compacted; runs in progress were stopped."""

    def __init__(self, finished: int, stopped: int) -> None:
        super().__init__(f"{finished} finished runs kept, {stopped} stopped")
        self.finished, self.stopped = finished, stopped


def run_batch(specs: RunPlan | list[RunSpec], store: ResultStore, executor: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True,
              on_row: Callable[[dict[str, Any]], None] | None = None, fork_server: bool = True) -> None:
    """Execute runs not yet in the store; each finished row is written at once.

    Ctrl-C stops launching at once, terminates the runs in progress, compacts the finished rows and
    raises ``BatchInterrupted``.  ``fork_server=False`` starts a fresh worker process per run (the
    local executor's former way, kept for ``benchmarks/batch_speedup.py``).  A row that cannot be written (disk full) stops the batch the same
    way with a one-line ``CorridorError``; the rows already written stay (``--resume`` continues)."""
    finished = store.finished()
    total = len(specs)
    todo = (s for s in specs if s.run_id not in finished)
    if isinstance(specs, RunPlan):
        order: Callable[[str], int] | list[str] = specs.rank
        n_todo = total - sum(1 for r in finished if specs.rank(r) < total)
    else:
        order = [s.run_id for s in specs]
        n_todo = sum(1 for s in specs if s.run_id not in finished)
    bar = _progress(total, total - n_todo, progress)
    said: list[bool] = []  # the local executor said it is stopping (the interrupt reached it)
    rows = _ray(todo, address) if executor == "ray" else run_local(todo, max(1, workers), fork_server, said)
    written = 0
    try:
        for row in rows:
            try:
                store.write(row)
            except OSError as exc:
                raise CorridorError(f"cannot write the row of {row['run_id']} to {store.parts} "
                                    f"({exc.strerror or exc}); the batch stopped, {written} rows of this "
                                    "session are kept: free space and continue with --resume") from None
            written += 1
            bar.update(1)
            bar.set_postfix_str(f"{row['run_id']} {row['status']}")
            if on_row:
                on_row(row)
    except KeyboardInterrupt:
        bar.close()
        if not said:  # Ray, or Ctrl-C while this loop (not the local executor) had control
            _say_stopping(None)
        rows.close()  # terminates the workers (a no-op once the local executor has stopped them)
        store.compact(order)
        raise BatchInterrupted(written, n_todo - written) from None
    finally:
        bar.close()
        rows.close()
    store.compact(order)


def _progress(total: int, initial: int, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="runs", unit="run", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)
