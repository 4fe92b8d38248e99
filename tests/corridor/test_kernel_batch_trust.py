"""Batches never destroy or mislabel data: no implicit deletion, --resume only of the same batch, one
batch per folder, per-field random streams, a dead worker costs one row, Ctrl-C stops at once, lazy
run expansion, write failures are one line.  Most use the METANET benchmark (no SUMO: a run takes
about a second) so each behaviour is checked on real runs."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from corridor.cli import main
from tests.conftest import REPO, SCENARIOS

HEGYI = str(SCENARIOS / "hegyi_benchmark.yaml")
MERGING = str(SCENARIOS / "merging.yaml")
FAST = ["--set", "duration=300", "--variant", "none", "--quiet", "--no-report", "--workers", "1"]
SLOWISH = ["--set", "duration=40", "--set", "warmup=5", "--variant", "sumo_default", "--no-report"]


def parts(out: Path) -> set[str]:
    return {p.stem for p in (out / "parts").glob("*.parquet")}


def test_second_batch_on_a_folder_is_refused_and_deletes_nothing(tmp_path, capsys):
    out = tmp_path / "b"
    assert main([HEGYI, *FAST, "--out", str(out)]) == 0
    before = (out / "runs.parquet").read_bytes()
    assert main([HEGYI, *FAST, "--out", str(out), "--set", "duration=200"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "already holds a batch" in err and "--resume" in err and "--overwrite" in err
    assert (out / "runs.parquet").read_bytes() == before and parts(out) == {"none-s0"}
    # explicit --overwrite replaces it; a folder that holds no batch is never touched
    assert main([HEGYI, *FAST, "--out", str(out), "--overwrite", "--seed", "5"]) == 0
    assert parts(out) == {"none-s5"}
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    assert main([HEGYI, *FAST, "--out", str(other), "--overwrite"]) == 2
    assert "holds no corridor batch" in capsys.readouterr().err
    assert (other / "notes.txt").read_text() == "keep me"


def test_resume_with_other_settings_is_refused_naming_the_difference(tmp_path, capsys):
    out = tmp_path / "r"
    assert main([HEGYI, *FAST, "--out", str(out)]) == 0
    manifest = json.loads((out / "batch.json").read_text())
    assert manifest["scenario"] == "hegyi_benchmark" and len(manifest["scenario_sha256"]) == 64
    assert main([HEGYI, *FAST, "--out", str(out), "--resume", "--set", "duration=200"]) == 2
    err = capsys.readouterr().err
    assert "duration: 300 -> 200" in err and err.count("\n") == 1
    # the same settings extend the batch: the stored run is kept, the new seed runs
    mtime = (out / "parts" / "none-s0.parquet").stat().st_mtime_ns
    assert main([HEGYI, *FAST, "--out", str(out), "--resume", "--runs", "2"]) == 0
    assert parts(out) == {"none-s0", "none-s1"}
    assert (out / "parts" / "none-s0.parquet").stat().st_mtime_ns == mtime
    # a changed scenario file is a changed batch too
    edited = tmp_path / "edited.yaml"
    edited.write_text(f"extends: {HEGYI}\ndescription: edited\n")
    assert main([str(edited), *FAST, "--out", str(out), "--resume"]) == 2
    assert "description" in capsys.readouterr().err


def test_two_batches_on_one_folder_second_is_refused(tmp_path, capsys):
    from corridor.batchdir import manifest_for, open_batch_dir

    out = tmp_path / "locked"
    held = open_batch_dir(out, manifest_for("x", "x.yaml", {"name": "x"}, []))
    try:
        assert main([HEGYI, *FAST, "--out", str(out), "--resume"]) == 2
        err = capsys.readouterr().err
        assert f"another batch (pid {os.getpid()})" in err
    finally:
        held.close()
    assert main([HEGYI, *FAST, "--out", str(out), "--overwrite"]) == 0  # free again once released


def test_fixing_one_randomized_field_leaves_the_others_draws(tmp_path):
    from corridor.batch import draws_for
    from corridor.scenario import load

    full, _ = load(MERGING)
    fixed, _ = load(MERGING, ["channels.v2x.loss.p=0.3"])
    assert "channels.v2x.loss.p" in full.randomize and "channels.v2x.loss.p" not in fixed.randomize
    for seed in range(5):
        a, b = draws_for(full, seed), draws_for(fixed, seed)
        assert set(a) - set(b) == {"channels.v2x.loss.p"}
        assert all(a[k] == b[k] for k in b)
    assert draws_for(full, 0) != draws_for(full, 1)


def test_out_that_is_a_file_or_cannot_be_written_is_one_line(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("")
    assert main([HEGYI, *FAST, "--out", str(f)]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert main([HEGYI, *FAST, "--out", "/proc/corridor-cannot-write/x"]) == 2
    err = capsys.readouterr().err
    assert "cannot write there" in err and err.count("\n") == 1


def test_a_write_failure_stops_the_batch_with_one_line_and_keeps_rows(tmp_path):
    from corridor.batch import expand, run_batch
    from corridor.errors import CorridorError
    from corridor.results import ResultStore
    from corridor.scenario import load

    class FullDisk(ResultStore):
        def write(self, row):
            if len(list(self.parts.glob("*.parquet"))) >= 1:
                (self.parts / f".{row['run_id']}.tmp").write_bytes(b"")  # what a cut-off write leaves
                raise OSError(errno.ENOSPC, "No space left on device")
            super().write(row)

    sc, raw = load(HEGYI, ["duration=300"])
    plan = expand(sc, raw, HEGYI, runs=4, variants=["none"], out_dir=str(tmp_path))
    with pytest.raises(CorridorError, match="No space left on device.*--resume"):
        run_batch(plan, FullDisk(tmp_path), workers=1, progress=False)
    assert parts(tmp_path) == {"none-s0"}
    store = ResultStore(tmp_path)  # reopening (--resume) clears the cut-off part
    assert not list(store.parts.glob(".*.tmp"))


def test_run_plan_is_lazy_and_ranks_run_ids():
    from corridor.batch import expand
    from corridor.scenario import load

    sc, raw = load(MERGING)
    plan = expand(sc, raw, MERGING, runs=10**9, seed=3)
    assert len(plan) == 4 * 10**9
    last = plan[-1]
    assert last.run_id == f"v2x_cps-s{3 + 10**9 - 1}" and plan.rank(last.run_id) == len(plan) - 1
    assert plan.rank("human-s3") == 0 and plan.rank("nope-s3") == len(plan)
    assert [s.run_id for s in list(expand(sc, raw, MERGING, runs=2))] == \
        ["human-s0", "sumo_default-s0", "v2x_fifo-s0", "v2x_cps-s0",
         "human-s1", "sumo_default-s1", "v2x_fifo-s1", "v2x_cps-s1"]


def _start(out: Path, runs: int, *extra: str) -> subprocess.Popen:
    args = [sys.executable, "-m", "corridor.cli", MERGING, *SLOWISH, "--out", str(out), "--runs", str(runs),
            "--workers", "2", *extra]
    return subprocess.Popen(args, cwd=REPO, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def _wait_for(cond, timeout: float = 300) -> None:
    deadline = time.time() + timeout
    while not cond():
        assert time.time() < deadline, "timed out"
        time.sleep(0.05)


def _workers(pid: int) -> list[int]:
    kids = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()
    return [int(k) for k in kids if b"corridor.worker" in Path(f"/proc/{k}/cmdline").read_bytes()]


def test_a_killed_worker_costs_its_own_row_only(tmp_path):
    out = tmp_path / "k"
    proc = _start(out, 4)
    _wait_for(lambda: len(_workers(proc.pid)) == 2)
    victim = _workers(proc.pid)[0]
    os.kill(victim, signal.SIGKILL)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err[-2000:]
    df = pd.read_parquet(out / "runs.parquet")
    assert len(df) == 4
    bad = df[df["status"] == "error"]
    assert len(bad) == 1 and "worker process died (signal SIGKILL)" in bad["error"].iloc[0]


def test_ctrl_c_stops_at_once_keeps_finished_rows_and_exits_130(tmp_path):
    out = tmp_path / "c"
    proc = _start(out, 400)  # fork servers run these in ~0.1-0.3 s: many runs, so the SIGINT lands mid-batch
    # whether the machine is idle (60 runs could all finish first) or loaded
    _wait_for(lambda: len(parts(out)) >= 1)
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C sends: the whole process group
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert "runs in progress; finished runs are kept" in err and "--resume" in err
    kept = parts(out)
    assert 1 <= len(kept) < 400
    assert set(pd.read_parquet(out / "runs.parquet")["run_id"]) == kept
    time.sleep(1.0)
    assert parts(out) == kept  # nothing was launched after the interrupt
    assert not _workers(proc.pid)


def test_python_api_gives_the_cli_rows(tmp_path):
    from corridor.api import run

    assert main([HEGYI, *FAST, "--runs", "2", "--out", str(tmp_path / "cli")]) == 0
    res = run(HEGYI, runs=2, sets=["duration=300"], variants=["none"], out=tmp_path / "api", report=False,
              workers=1)
    cli_rows = pd.read_parquet(tmp_path / "cli" / "runs.parquet")
    cols = [c for c in cli_rows.columns if c not in ("wall_s", "traceback")]
    pd.testing.assert_frame_equal(res.rows[cols], cli_rows[cols])
    sig = res.signals("none-s0")
    assert any(k.endswith(".t") for k in sig)


def test_seeds_beyond_the_seed_range_are_one_line_and_create_nothing(capsys, tmp_path):
    out = tmp_path / "never"
    assert main([HEGYI, *FAST, "--seed", str(2**32 - 2), "--runs", "3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "must lie in 0..4294967295" in err and err.count("\n") == 1
    assert not out.exists()


def test_workers_die_with_a_killed_parent(tmp_path):
    out = tmp_path / "orphans"
    proc = _start(out, 4, "--set", "duration=600")  # a run takes far longer than the 10 s allowed below
    _wait_for(lambda: len(_workers(proc.pid)) == 2)
    workers = _workers(proc.pid)
    os.killpg(proc.pid, signal.SIGKILL)  # the parent's group only: workers have sessions of their own
    proc.wait()
    _wait_for(lambda: not any(Path(f"/proc/{w}").exists() and b"corridor.worker" in
                              Path(f"/proc/{w}/cmdline").read_bytes() for w in workers), timeout=10)
