"""The local executor's fork servers: one server per worker slot runs run after run, each run in a
forked process of its own, and the rows equal those of a fresh process per run."""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import subprocess
import time

import pandas as pd

import corridor.batch as batch
from corridor.scenario import load
from tests.conftest import SCENARIOS

VOLATILE = re.compile(r"(^|[._])(wall|rtf|traceback)($|[._])|solve|_time_s$|cpu")  # the machine's timings


HEGYI = str(SCENARIOS / "hegyi_benchmark.yaml")


def _rows(monkeypatch, fork_server: bool, workers: int) -> tuple[pd.DataFrame, int]:
    started = []
    spawn = batch.Worker.spawn
    monkeypatch.setattr(batch.Worker, "spawn", lambda serve: started.append(serve) or spawn(serve))
    sc, raw = load(HEGYI, ["duration=300"])
    plan = batch.expand(sc, raw, HEGYI, runs=4, variants=["none", "alinea"])
    rows = list(batch.run_local(plan, workers, fork_server))
    df = pd.DataFrame(rows).drop(columns=["wall_s"]).sort_values("run_id").reset_index(drop=True)
    return df[sorted(df.columns)], len(started)  # columns in a fixed order (rows finish in any order)


def test_fork_servers_give_the_rows_of_a_fresh_process_per_run(monkeypatch):
    forked, n_servers = _rows(monkeypatch, True, 2)
    fresh, n_processes = _rows(monkeypatch, False, 2)
    assert n_servers == 2 and n_processes == 8  # two slots serve all 8 runs; the old way spawns 8
    assert (forked["status"] == "ok").all() and len(forked) == 8
    pd.testing.assert_frame_equal(forked, fresh)


def test_a_killed_run_costs_its_row_and_its_server_serves_on():
    sc, raw = load(HEGYI, [])  # the full 2.5 h: long enough to be killed while it runs
    long_run = batch.expand(sc, raw, HEGYI, runs=1, variants=["none"])[0]
    sc, raw = load(HEGYI, ["duration=300"])
    short_run = batch.expand(sc, raw, HEGYI, runs=1, variants=["none"], seed=1)[0]
    w = batch.Worker.spawn(True)
    try:
        w.send(long_run)
        deadline = time.time() + 120
        while not (kids := subprocess.run(["pgrep", "-P", str(w.proc.pid)], capture_output=True,
                                          text=True).stdout.split()):
            assert time.time() < deadline, "no forked run appeared"
            time.sleep(0.02)
        os.kill(int(kids[0]), signal.SIGKILL)
        code, row = w.wait_row()
        assert code == -signal.SIGKILL and row["status"] == "error"
        assert "worker process died (signal SIGKILL)" in row["error"]
        w.send(short_run)  # the same server runs the next spec
        code, row = w.wait_row()
        assert code == 0 and row["status"] == "ok"
        assert w.proc.poll() is None
    finally:
        w.kill()


def test_a_server_that_retires_loses_no_run(tmp_path, monkeypatch):
    """highway-env's import starts a native thread, so a fork server that learned the parking lot's
    modules (when its runner ended) retires.  It says so in its frame: the next spec goes to a fresh
    server (it used to be sent to the retiring one and came back as 'worker process died (exit code
    0)').  A runner per run (CORRIDOR_RUNNER_RUNS=1) makes the server learn after every run."""
    from corridor.api import run

    monkeypatch.setenv("CORRIDOR_RUNNER_RUNS", "1")
    started = []
    spawn = batch.Worker.spawn
    monkeypatch.setattr(batch.Worker, "spawn", lambda serve: started.append(serve) or spawn(serve))
    res = run(str(SCENARIOS / "parking_lot.yaml"), runs=3, sets=["duration=2"], out=tmp_path / "b",
              report=False, workers=1)
    assert list(res.rows["status"]) == ["ok"] * 3, res.rows.get("error")
    assert len(started) == 3  # each server retired after its run


def _mixed_plan() -> list:
    """Runs of different scenarios, backends and controllers, one after another (a runner runs them
    in one process), the merging ones twice: a run must not see what the runs before it left."""
    plan = []
    for path, sets, variants, runs in (
            ("merging.yaml", ["duration=40", "warmup=0"], ["sumo_default", "v2x_cps"], 2),
            ("hegyi_benchmark.yaml", ["duration=300"], ["alinea"], 1),
            ("uav_encounter.yaml", ["duration=8"], None, 1),
            ("merging.yaml", ["duration=40", "warmup=0"], ["v2x_cps", "sumo_default"], 2)):
        sc, raw = load(str(SCENARIOS / path), sets)
        plan.extend(batch.expand(sc, raw, str(SCENARIOS / path), runs=runs, variants=variants))
    return plan


def test_runs_sharing_a_runner_give_the_rows_of_a_fresh_process_each():
    plan = _mixed_plan()
    shared = list(batch.run_local(plan, 1, True))  # one server, one runner: every run in one process
    fresh = list(batch.run_local(plan, 1, False))
    assert len(shared) == len(plan) and all(r["status"] == "ok" for r in shared), [r.get("error") for r in shared]
    key = lambda r: (r["scenario"], r["run_id"])  # noqa: E731 - the merging runs appear twice
    for a, b in zip(sorted(shared, key=key), sorted(fresh, key=key), strict=True):
        a, b = ({k: v for k, v in r.items() if not VOLATILE.search(k)} for r in (a, b))
        assert a.keys() == b.keys()
        for k in a:  # NaN == NaN here: the same row, value for value
            assert a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]), (a["run_id"], k, a[k], b[k])


def _runner_pids(server_pid: int) -> list[str]:
    return subprocess.run(["pgrep", "-P", str(server_pid)], capture_output=True, text=True).stdout.split()


def test_a_failed_run_ends_its_runner_and_the_next_run_gets_a_fresh_one():
    sc, raw = load(HEGYI, ["duration=300"])
    good = batch.expand(sc, raw, HEGYI, runs=2, variants=["none"])
    bad = dataclasses.replace(good[0], run_id="bad", overrides={"controllers": {"nope": {"type": "no_such_controller"}}})
    w = batch.Worker.spawn(True)
    try:
        w.send(good[0])
        assert w.wait_row()[0] == 0
        first = _runner_pids(w.proc.pid)
        assert len(first) == 1  # the runner waits for the next spec
        w.send(good[1])
        assert w.wait_row()[0] == 0 and _runner_pids(w.proc.pid) == first  # the same process ran both
        w.send(bad)
        code, row = w.wait_row()
        assert code == 0 and row["status"] == "error" and "no_such_controller" in row["error"]
        assert _runner_pids(w.proc.pid) == []  # it ended with the failed run
        w.send(good[0])
        code, row = w.wait_row()
        assert code == 0 and row["status"] == "ok"
        again = _runner_pids(w.proc.pid)
        assert len(again) == 1 and again != first
    finally:
        w.kill()
