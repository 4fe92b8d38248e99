"""A batch worker process: ``python -m corridor.worker FD PARENT_PID`` reads one pickled ``RunSpec`` from stdin,
runs it, and writes the pickled row to file descriptor ``FD``.

The local executor starts each worker in a session of its own, so a terminal's Ctrl-C (sent to the
foreground process group) reaches only the parent, which then stops the workers itself; nothing in
the parent has to ignore or block SIGINT, so no interrupt is ever lost.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys

PR_SET_PDEATHSIG = 1  # linux/prctl.h


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


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), int(sys.argv[2])))
