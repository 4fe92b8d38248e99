"""Every file a run writes lives under the batch's output folder: the MAVLink log path is relative
to it (absolute paths and '..' are refused at load, in one line), carries the run id, and no path
(symlinked folder, run id) can lead out of the folder."""

from __future__ import annotations

import os

import pytest

from corridor.cli import main
from corridor.engine import RunContext, path_inside, relative_output_path
from tests.conftest import SCENARIOS

ENCOUNTER = SCENARIOS / "uav_encounter.yaml"


def one_line_exit_2(capsys, *argv: str) -> str:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("bad", ["/tmp/victim.bin", "../victim.bin", "logs/../../victim.bin", "~/victim.bin"])
def test_log_path_outside_the_output_folder_is_refused_at_load(capsys, tmp_path, bad):
    victim = tmp_path / "victim.bin"
    victim.write_bytes(b"precious")
    err = one_line_exit_2(capsys, str(ENCOUNTER), "--out", str(tmp_path / "out"), "--set", "duration=0.5",
                          "--set", f"backends.link.params.log_path={bad}")
    assert "backends.link.params.log_path" in err and "output folder" in err
    assert victim.read_bytes() == b"precious"
    assert not (tmp_path / "out" / "runs.parquet").exists()


def test_log_is_written_under_out_with_the_run_id(tmp_path):
    out = tmp_path / "out"
    code = main([str(ENCOUNTER), "--out", str(out), "--variant", "none", "--runs", "2", "--workers", "1",
                 "--set", "duration=0.5", "--set", "backends.link.params.log_path=mavlink/link.tlog",
                 "--no-report", "--quiet"])
    assert code == 0
    logs = sorted(p.name for p in (out / "mavlink").iterdir())
    assert logs == ["link-none-s0.tlog", "link-none-s1.tlog"]  # one per run, none overwritten
    assert all((out / "mavlink" / n).stat().st_size > 0 for n in logs)


def test_relative_output_path_rules():
    assert relative_output_path("a/b.tlog") == "a/b.tlog"
    for bad in ("/etc/passwd", "..", "a/../../b", "", "C:\\x", "a\\..\\b"):
        with pytest.raises(ValueError):
            relative_output_path(bad)


def test_output_path_cannot_escape_through_a_symlink_or_the_run_id(tmp_path):
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    os.symlink(outside, out / "link")
    ctx = RunContext(run_seed=0, dt=0.1, duration=1.0, out_dir=out, run_id="none-s0")
    assert ctx.output_path("logs/x.bin") == (out / "logs" / "x-none-s0.bin").resolve()
    with pytest.raises(ValueError, match="escapes"):
        ctx.output_path("link/x.bin")
    with pytest.raises(ValueError, match="escapes"):
        path_inside(out / "signals", "../../x.npz")
    bad = RunContext(run_seed=0, dt=0.1, duration=1.0, out_dir=out, run_id="../../x")
    with pytest.raises(ValueError):
        bad.output_path("x.bin")


def test_signals_file_name_cannot_escape(tmp_path):
    from corridor.run import simulate
    from corridor.scenario import load

    sc, _ = load(SCENARIOS / "hegyi_benchmark.yaml", ["duration=20"])
    with pytest.raises(ValueError):
        simulate(sc, 0, out_dir=str(tmp_path / "out"), run_id="../../escaped")
    assert not (tmp_path / "escaped.npz").exists()
    simulate(sc, 0, out_dir=str(tmp_path / "out"), run_id="none-s0")
    assert (tmp_path / "out" / "signals" / "none-s0.npz").exists()
