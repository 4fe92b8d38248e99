"""Batch worker processes, two kinds:

``python -m corridor.worker FD PARENT_PID`` (one run): reads one pickled ``RunSpec`` from stdin, runs
it, and writes the pickled row to file descriptor ``FD``.

``python -m corridor.worker --serve FD PARENT_PID`` (a fork server, one per batch worker slot):
imports corridor once, then reads length-prefixed pickled ``RunSpec`` frames from stdin until end of
file.  It forks a *runner*, which runs spec after spec in its own process and hands each row back
through a pipe of its own; the server then writes one frame ``(length, exit status, row bytes)`` to
``FD``.  Runs pay no interpreter start-up or imports (about 1.6 s per run before the fork server)
and, since the runner is forked once and not per run, no fork either (a fork per run cost ~0.03 s
of CPU, more when two servers forked side by side: 20 % of a 60 s merging run).  A run that fails
(a ``status=error`` row), a runner that dies (segfault, kill -9: that run's row says so), and every
``RUNS_PER_RUNNER``-th run end the runner; the server forks a fresh one for the next spec, so a run
never starts in a process whose last run failed.  Before that fork the server imports the modules
the runs imported (``_learn``), so the new runner finds them loaded.  The rows do not depend on
which runs shared a runner (the engine builds every component afresh and closes it, libsumo
included; tested against a fresh process per run), and ``CORRIDOR_RUNNER_RUNS=1`` restores a
process of its own per run.

Both kinds run in a session of their own (the local executor starts them so), so a terminal's Ctrl-C
(sent to the foreground process group) reaches only the parent, which then stops the workers itself;
nothing in the parent has to ignore or block SIGINT, so no interrupt is ever lost.  Each worker and
each forked run asks the kernel for SIGKILL when its parent dies (PR_SET_PDEATHSIG): a killed batch
leaves no orphans, and a killed server takes its run with it (the batch records that row as died).
"""

from __future__ import annotations

import gc
import os
import pickle
import signal
import struct
import sys
from dataclasses import dataclass
from typing import BinaryIO

PR_SET_PDEATHSIG = 1  # linux/prctl.h
# server -> parent: row length [bytes], run's wait status (0: exited 0), whether the server retires
# after this frame (the parent then sends it nothing more: a spec sent to a retiring server was lost)
FRAME = struct.Struct("<Qi?")
SPEC_LEN = struct.Struct("<Q")  # parent -> server: spec length [bytes]


def _die_with_parent(parent_pid: int) -> None:
    """A worker lives in its own session, so a signal to the parent's group does not reach it: ask the
    kernel to kill it when the parent dies (Linux), and give up at once if the parent is gone already."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: the parent's pipe closing still ends the row
        pass
    if os.getppid() != parent_pid:
        os._exit(1)


def main(fd: int, parent_pid: int) -> int:
    _die_with_parent(parent_pid)
    spec = pickle.load(sys.stdin.buffer)
    from corridor.run import execute  # after the spec: a bad pickle fails before heavy imports

    row = execute(spec)
    data = pickle.dumps(row, protocol=pickle.HIGHEST_PROTOCOL)
    with os.fdopen(fd, "wb") as out:
        out.write(data)
    return 0


def _read_exact(src: BinaryIO, n: int) -> bytes | None:
    """``n`` bytes from ``src``, or None at end of file."""
    buf = bytearray()
    while len(buf) < n:
        chunk = src.read(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


def _learn(modules: list[str]) -> None:
    """Import into the server the modules a finished run imported, so later forks find them loaded
    (a scenario's backends, controllers, CasADi, libsumo, ...).  Best effort: a module that fails to
    import here is imported again, and reports its error, in the run that needs it."""
    import importlib

    for name in modules:
        if name not in sys.modules:
            try:
                importlib.import_module(name)
            except BaseException:  # noqa: BLE001 - see above
                pass


# a runner retires after this many runs (a bound on anything a run leaves behind); 1: a fresh process
# per run, as isolated as a run can be (for a plug-in that keeps state between runs, say)
RUNS_PER_RUNNER = int(os.environ.get("CORRIDOR_RUNNER_RUNS", "200"))


def _runner(server_pid: int, spec_r: int, row_w: int, keep: set[int]) -> None:
    """In the forked runner: run spec after spec from ``spec_r`` in this process, one frame
    ``(row bytes, modules the run imported, retire)`` per run on ``row_w``; exit without returning
    after a run that failed (its state is not trusted for the next), after ``RUNS_PER_RUNNER`` runs,
    or at end of file."""
    code = 1
    try:
        for fd in (0, *keep):  # the parent's pipes are the server's business only
            os.close(fd)
        _die_with_parent(server_pid)
        from corridor.run import execute

        src, out = os.fdopen(spec_r, "rb"), os.fdopen(row_w, "wb")
        for done in range(1, RUNS_PER_RUNNER + 1):
            head = _read_exact(src, SPEC_LEN.size)
            if head is None:
                break
            body = _read_exact(src, SPEC_LEN.unpack(head)[0])
            if body is None:
                break
            before = set(sys.modules)
            row = execute(pickle.loads(body))
            new = [m for m in sys.modules if m not in before and not m.startswith("_") and m != "__main__"]
            retire = row.get("status") != "ok" or done == RUNS_PER_RUNNER
            data = pickle.dumps((pickle.dumps(row, protocol=pickle.HIGHEST_PROTOCOL), new, retire),
                                protocol=pickle.HIGHEST_PROTOCOL)
            sys.stdout.flush()
            sys.stderr.flush()
            out.write(SPEC_LEN.pack(len(data)) + data)
            out.flush()
            if retire:
                break
        code = 0
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


@dataclass
class _Runner:
    """A forked process that runs the server's specs one after another: the server writes a spec
    frame to ``spec_w`` and reads the run's frame from ``row_r``."""

    pid: int
    spec_w: BinaryIO
    row_r: BinaryIO


def _fork_runner() -> _Runner:
    spec_r, spec_w = os.pipe()
    row_r, row_w = os.pipe()
    server = os.getpid()
    gc.freeze()  # the server's objects stay out of the runner's collections: fewer copy-on-write pages
    pid = os.fork()
    if pid == 0:
        os.close(spec_w)
        os.close(row_r)
        _runner(server, spec_r, row_w, _SERVER_FDS)
    os.close(spec_r)
    os.close(row_w)
    return _Runner(pid, os.fdopen(spec_w, "wb"), os.fdopen(row_r, "rb"))


def _end_runner(runner: _Runner) -> int:
    """Reap a runner that finished or died; its exit code (negative: killed by that signal)."""
    for f in (runner.spec_w, runner.row_r):
        try:
            f.close()
        except OSError:
            pass
    _, status = os.waitpid(runner.pid, 0)
    return os.waitstatus_to_exitcode(status)


def _run_in(runner: _Runner, body: bytes, learned: list[str]) -> tuple[bytes, int, bool]:
    """Hand one pickled spec to ``runner``; (row bytes, exit code, runner gone).  A runner that died
    before its frame was whole gives empty row bytes and its exit code.  The modules the run
    imported are added to ``learned``."""
    try:
        runner.spec_w.write(SPEC_LEN.pack(len(body)) + body)
        runner.spec_w.flush()
    except OSError:  # died before it read the spec: its exit code says how
        pass
    head = _read_exact(runner.row_r, SPEC_LEN.size)
    frame = _read_exact(runner.row_r, SPEC_LEN.unpack(head)[0]) if head is not None else None
    if frame is None:
        return b"", _end_runner(runner), True
    row, modules, retire = pickle.loads(frame)
    learned.extend(modules)
    return row, (_end_runner(runner) if retire else 0), retire


_SERVER_FDS: set[int] = set()


def serve(fd: int, parent_pid: int) -> int:
    """Run each spec frame on stdin in the runner (forked when there is none); one result frame per
    run on ``fd``; stop at end of file."""
    _die_with_parent(parent_pid)
    _SERVER_FDS.add(fd)
    import corridor.run  # noqa: F401 - the imports every run needs, loaded once for all forks

    out = os.fdopen(fd, "wb")
    src = sys.stdin.buffer
    runner: _Runner | None = None
    learned: list[str] = []  # modules the runs imported, imported here before the next runner is forked
    try:
        while (head := _read_exact(src, SPEC_LEN.size)) is not None:
            body = _read_exact(src, SPEC_LEN.unpack(head)[0])
            if body is None:
                break
            if runner is None:
                runner = _fork_runner()
            data, code, gone = _run_in(runner, body, learned)
            retire = False
            if gone:
                runner = None
                _learn(learned)  # so the next runner finds them loaded
                learned.clear()
                # a learned module started a thread (a Rust runtime, say): forking a multi-threaded
                # process is unsafe, so retire, and say so in the frame, before the parent can hand
                # this server more work
                retire = _threads() > 1
            out.write(FRAME.pack(len(data), code, retire) + data)
            out.flush()
            if retire:
                break
    finally:
        if runner is not None:
            runner.spec_w.close()  # end of file: the runner exits
            _end_runner(runner)
    return 0


def _threads() -> int:
    """Native threads of this process (Linux), else Python's own count."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        import threading

        return threading.active_count()


if __name__ == "__main__":
    if sys.argv[1] == "--serve":
        sys.exit(serve(int(sys.argv[2]), int(sys.argv[3])))
    sys.exit(main(int(sys.argv[1]), int(sys.argv[2])))
