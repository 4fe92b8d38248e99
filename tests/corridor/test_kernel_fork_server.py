"""The local executor's fork servers: one server per worker slot runs run after run, each run in a
forked process of its own, and the rows equal those of a fresh process per run."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd

import corridor.batch as batch
from corridor.scenario import load
from corridor.worker import FRAME

ROOT = Path(__file__).resolve().parents[2]
HEGYI = str(ROOT / "scenarios" / "hegyi_benchmark.yaml")


def _rows(monkeypatch, fork_server: bool, workers: int) -> tuple[pd.DataFrame, int]:
    started = []
    spawn = batch._spawn
    monkeypatch.setattr(batch, "_spawn", lambda serve: started.append(serve) or spawn(serve))
    sc, raw = load(HEGYI, ["duration=300"])
    plan = batch.expand(sc, raw, HEGYI, runs=4, variants=["none", "alinea"])
    rows = list(batch._local(plan, workers, fork_server))
    df = pd.DataFrame(rows).drop(columns=["wall_s"]).sort_values("run_id").reset_index(drop=True)
    return df[sorted(df.columns)], len(started)  # columns in a fixed order (rows finish in any order)


def test_fork_servers_give_the_rows_of_a_fresh_process_per_run(monkeypatch):
    forked, n_servers = _rows(monkeypatch, True, 2)
    fresh, n_processes = _rows(monkeypatch, False, 2)
    assert n_servers == 2 and n_processes == 8  # two slots serve all 8 runs; the old way spawns 8
    assert (forked["status"] == "ok").all() and len(forked) == 8
    pd.testing.assert_frame_equal(forked, fresh)


def _frame(w: batch._Worker) -> tuple[int, bytes]:
    """Block until the server's next result frame: (exit code of the run, row bytes)."""
    os.set_blocking(w.fd, True)
    data = bytearray()
    while len(data) < FRAME.size or len(data) < FRAME.size + FRAME.unpack_from(data)[0]:
        chunk = os.read(w.fd, 1 << 20)
        assert chunk, "the server closed its pipe"
        data += chunk
    n, code, _retiring = FRAME.unpack_from(data)
    return code, bytes(data[FRAME.size:FRAME.size + n])


def test_a_killed_run_costs_its_row_and_its_server_serves_on():
    sc, raw = load(HEGYI, [])  # the full 2.5 h: long enough to be killed while it runs
    long_run = batch.expand(sc, raw, HEGYI, runs=1, variants=["none"])[0]
    sc, raw = load(HEGYI, ["duration=300"])
    short_run = batch.expand(sc, raw, HEGYI, runs=1, variants=["none"], seed=1)[0]
    w = batch._spawn(True)
    try:
        batch._send(w, long_run)
        deadline = time.time() + 120
        while not (kids := subprocess.run(["pgrep", "-P", str(w.proc.pid)], capture_output=True,
                                          text=True).stdout.split()):
            assert time.time() < deadline, "no forked run appeared"
            time.sleep(0.02)
        os.kill(int(kids[0]), signal.SIGKILL)
        code, data = _frame(w)
        row = batch._row(long_run, data, code)
        assert code == -signal.SIGKILL and row["status"] == "error"
        assert "worker process died (signal SIGKILL)" in row["error"]
        batch._send(w, short_run)  # the same server runs the next spec
        code, data = _frame(w)
        assert code == 0 and batch._row(short_run, data, code)["status"] == "ok"
        assert w.proc.poll() is None
    finally:
        os.kill(w.proc.pid, signal.SIGKILL)
        w.proc.wait()
        os.close(w.fd)


def test_a_server_that_retires_loses_no_run(tmp_path):
    """highway-env's import starts a native thread, so a fork server that learned the parking lot's
    modules retires after its run.  It says so in its frame: the next spec goes to a fresh server (it
    used to be sent to the retiring one and came back as 'worker process died (exit code 0)')."""
    from corridor.api import run

    res = run(str(ROOT / "scenarios" / "parking_lot.yaml"), runs=3, sets=["duration=2"], out=tmp_path / "b",
              report=False, workers=1)
    assert list(res.rows["status"]) == ["ok"] * 3, res.rows.get("error")
