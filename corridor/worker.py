"""Batch worker processes, two kinds:

``python -m corridor.worker FD PARENT_PID`` (one run): reads one pickled ``RunSpec`` from stdin, runs
it, and writes the pickled row to file descriptor ``FD``.

``python -m corridor.worker --serve FD PARENT_PID`` (a fork server, one per batch worker slot):
imports corridor once, then reads length-prefixed pickled ``RunSpec`` frames from stdin until end of
file.  For each it forks a child that runs the spec and hands the row back through a pipe of its
own; the server then writes one frame ``(length, exit status, row bytes)`` to ``FD``.  So every run
is still a process of its own (its own libsumo, its own module state, copied from the server at the
fork) but pays no interpreter start-up or imports (about 1.6 s per run before).  Each run reports
the modules it imported; the server imports them after the run (``_learn``), so later runs of that
scenario find them loaded too.

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
from typing import Any, BinaryIO

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


def _run_child(spec: Any, server_pid: int, row_w: int, keep: set[int]) -> None:
    """In the forked child: run ``spec``, write (row bytes, modules it imported) to ``row_w``, exit
    without returning."""
    code, before = 1, set(sys.modules)
    try:
        for fd in (0, *keep):  # the parent's pipes are the server's business only
            os.close(fd)
        _die_with_parent(server_pid)
        from corridor.run import execute

        row = pickle.dumps(execute(spec), protocol=pickle.HIGHEST_PROTOCOL)
        new = [m for m in sys.modules if m not in before and not m.startswith("_") and m != "__main__"]
        data = pickle.dumps((row, new), protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(row_w, "wb") as out:
            out.write(data)
        code = 0
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _fork_run(spec: Any) -> tuple[bytes, int]:
    """Run ``spec`` in a forked child; its row bytes (empty if it died first) and exit code
    (negative: killed by that signal).  Learns the modules the run imported."""
    r, w = os.pipe()
    server = os.getpid()
    gc.freeze()  # the server's objects stay out of the child's collections: fewer copy-on-write pages
    pid = os.fork()
    if pid == 0:
        os.close(r)
        _run_child(spec, server, w, _SERVER_FDS)
    os.close(w)
    with os.fdopen(r, "rb") as src:
        data = src.read()
    _, status = os.waitpid(pid, 0)
    code = os.waitstatus_to_exitcode(status)
    try:
        row, modules = pickle.loads(data)
    except Exception:  # noqa: BLE001 - died while writing: the parent records a died row
        return b"", code
    _learn(modules)
    return row, code


_SERVER_FDS: set[int] = set()


def serve(fd: int, parent_pid: int) -> int:
    """Fork a run per spec frame on stdin; one result frame per run on ``fd``; stop at end of file."""
    _die_with_parent(parent_pid)
    _SERVER_FDS.add(fd)
    import corridor.run  # noqa: F401 - the imports every run needs, loaded once for all forks

    out = os.fdopen(fd, "wb")
    src = sys.stdin.buffer
    while (head := _read_exact(src, SPEC_LEN.size)) is not None:
        body = _read_exact(src, SPEC_LEN.unpack(head)[0])
        if body is None:
            break
        data, code = _fork_run(pickle.loads(body))
        # a learned module started a thread (a Rust runtime, say): forking a multi-threaded process is
        # unsafe, so retire, and say so in the frame, before the parent can hand this server more work
        retire = _threads() > 1
        out.write(FRAME.pack(len(data), code, retire) + data)
        out.flush()
        if retire:
            break
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
