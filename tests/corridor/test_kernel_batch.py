"""Batches on the real merging scenario (short horizon): determinism, error rows, kill + resume,
the CLI end to end, the Rerun recording, and the Ray executor."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from tests.conftest import REPO, SCENARIOS

MERGING = SCENARIOS / "merging.yaml"
SHORT = ["--set", "duration=40", "--set", "warmup=5", "--variant", "sumo_default"]  # the V2X variants: tests/scenarios
METRICS = ["collisions", "vehicles_departed", "vehicles_arrived", "min_ttc_s", "hard_brakes",
           "throughput_vph", "delay_mean_s"]


def cli(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    exe = [sys.executable, "-m", "corridor.cli", *args]
    res = subprocess.run(exe, capture_output=True, text=True, cwd=REPO, timeout=600)
    if check and res.returncode != 0:
        raise AssertionError(f"exit {res.returncode}: {res.stderr[-2000:]}")
    return res


def test_batch_rows_summary_report_and_determinism(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    res = cli(str(MERGING), "--runs", "2", "--out", str(a), "--workers", "2", *SHORT)
    df = pd.read_parquet(a / "runs.parquet")
    assert list(df["run_id"]) == ["sumo_default-s0", "sumo_default-s1"]
    assert (df["status"] == "ok").all()
    assert {"run_id", "scenario", "variant", "seed", "status", "error", "wall_s", "sim_s", "collisions"} <= set(df.columns)
    assert (a / "report.html").stat().st_size > 5000
    assert "P(collision)" in res.stdout and "sumo_default" in res.stdout
    assert df["vehicles_departed"].min() > 20  # real traffic ran
    cli(str(MERGING), "--runs", "1", "--out", str(b), "--workers", "1", "--quiet", "--no-report", *SHORT)
    again = pd.read_parquet(b / "runs.parquet")
    pd.testing.assert_frame_equal(df.loc[[0], METRICS].reset_index(drop=True), again[METRICS])
    assert df.loc[0, "draw.road.demand.scale"] != df.loc[1, "draw.road.demand.scale"]


def test_failing_variant_is_an_error_row_and_others_complete(tmp_path):
    # valid at load (every variant is validated there: an invalid one is exit 2, see
    # test_kernel_cli_probes), failing at run time: a second SSM monitor writes the same columns
    sc = tmp_path / "broken.yaml"
    sc.write_text(f"extends: {MERGING}\nsweep:\n  sumo_default: {{}}\n"
                  "  broken: {monitors.ssm2: {type: surrogate_safety}}\n")
    res = cli(str(sc), "--runs", "1", "--out", str(tmp_path / "o"), "--quiet", *SHORT, "--variant", "broken",
              check=False)
    assert res.returncode == 1
    df = pd.read_parquet(tmp_path / "o" / "runs.parquet").set_index("variant")
    assert df.loc["sumo_default", "status"] == "ok"
    assert df.loc["broken", "status"] == "error"
    assert "written by both" in df.loc["broken", "error"]
    assert "broken-s0 failed" in res.stderr


def test_killed_batch_resumes_without_duplicates(tmp_path):
    out = tmp_path / "k"
    args = [sys.executable, "-m", "corridor.cli", str(MERGING), "--runs", "4", "--workers", "1",
            "--out", str(out), "--quiet", "--no-report", *SHORT]
    proc = subprocess.Popen(args, cwd=REPO, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and len(list((out / "parts").glob("*.parquet"))) < 1:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = {p.stem for p in (out / "parts").glob("*.parquet")}
    assert 1 <= len(done_before) < 4
    cli(*args[3:], "--resume")
    df = pd.read_parquet(out / "runs.parquet")
    assert sorted(df["run_id"]) == [f"sumo_default-s{i}" for i in range(4)]
    assert (df["status"] == "ok").all()


def test_rerun_recording_has_road_vehicles_and_scalars(tmp_path):
    from rerun.chunk import RrdReader

    rrd = tmp_path / "out.rrd"
    cli(str(MERGING), "--out", str(tmp_path / "r"), "--rerun", str(rrd), "--quiet", "--no-report", *SHORT)
    reader = RrdReader(rrd)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    paths = {c.entity_path for c in reader.stream()}
    assert {"/world/road/lanes", "/world/entities", "/metrics/min_ttc"} <= paths


def test_recording_does_not_change_the_trajectory(tmp_path):
    cli(str(MERGING), "--out", str(tmp_path / "x"), "--quiet", "--no-report", *SHORT)
    cli(str(MERGING), "--out", str(tmp_path / "y"), "--rerun", str(tmp_path / "y.rrd"), "--quiet",
        "--no-report", *SHORT)
    x = pd.read_parquet(tmp_path / "x" / "runs.parquet")[METRICS]
    y = pd.read_parquet(tmp_path / "y" / "runs.parquet")[METRICS]
    pd.testing.assert_frame_equal(x, y)


def test_ray_executor_gives_the_same_rows(tmp_path):
    pytest.importorskip("ray")
    cli(str(MERGING), "--runs", "2", "--out", str(tmp_path / "l"), "--quiet", "--no-report", *SHORT)
    cli(str(MERGING), "--runs", "2", "--out", str(tmp_path / "r"), "--executor", "ray", "--quiet",
        "--no-report", *SHORT)
    a = pd.read_parquet(tmp_path / "l" / "runs.parquet")
    b = pd.read_parquet(tmp_path / "r" / "runs.parquet")
    cols = [c for c in a.columns if c not in ("wall_s", "traceback")]
    pd.testing.assert_frame_equal(a[cols], b[cols])


def test_ray_actors_run_spec_after_spec_and_a_failed_run_is_one_error_row(tmp_path):
    """With Ray's actors (each runs spec after spec, replaced after a failed run) a failing run is one
    error row, and the other runs are ok with the rows of the local executor."""
    pytest.importorskip("ray")
    import dataclasses

    from corridor.batch import expand, run_batch
    from corridor.results import ResultStore
    from corridor.scenario import load

    hegyi = str(SCENARIOS / "hegyi_benchmark.yaml")
    sc, raw = load(hegyi, ["duration=300"])
    plan = list(expand(sc, raw, hegyi, runs=3, variants=["none", "alinea"]))
    plan[1] = dataclasses.replace(plan[1], overrides={"controllers": {"x": {"type": "no_such_controller"}}})
    rows = {}
    for ex in ("ray", "local"):
        store = ResultStore(tmp_path / ex)
        run_batch(plan, store, executor=ex, workers=2, progress=False)
        rows[ex] = store.read().sort_values("run_id").reset_index(drop=True)
    ray_rows = rows["ray"].set_index("run_id")
    bad = plan[1].run_id
    assert ray_rows.loc[bad, "status"] == "error" and "no_such_controller" in ray_rows.loc[bad, "error"]
    assert (ray_rows.drop(index=bad)["status"] == "ok").all() and len(ray_rows) == 6
    cols = [c for c in rows["local"].columns if c not in ("wall_s", "traceback")]
    pd.testing.assert_frame_equal(rows["ray"][cols], rows["local"][cols])


def test_local_workers_get_single_threaded_math_unless_the_user_chose(monkeypatch) -> None:
    from corridor.batch import WORKER_THREAD_ENV, run_local

    for var in WORKER_THREAD_ENV:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "4")
    assert list(run_local([], workers=1)) == []
    assert os.environ["OMP_NUM_THREADS"] == "1" and os.environ["OPENBLAS_NUM_THREADS"] == "1"
    assert os.environ["MKL_NUM_THREADS"] == "4"
