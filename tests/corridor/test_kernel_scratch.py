"""Files a run writes outside its batch folder (issue 30): per-run scratch under ``DIR/.tmp``, the
JSBSim aircraft folder in corridor's cache (not one temp folder per worker), no workdir in the
current directory."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from corridor import run as run_mod
from corridor.batch import expand
from corridor.cli import main
from corridor.scenario import load
from tests.conftest import REPO, SCENARIOS
from tests.corridor.rare_data import GAUSS


def test_build_refuses_the_current_directory_as_workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """benchmarks/air_ground_watch_time.py built with Path('.'): SUMO wrote routes.rou.xml into the
    repository root."""
    sc, _ = load(GAUSS)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="current directory"):
        run_mod.build(sc, 0, Path("."))
    run_mod.build(sc, 0, tmp_path / "scratch")  # any other folder is fine
    for bench in ("air_ground_watch_time.py", "uav_swarm_rtf.py"):
        assert 'Path(".")' not in (REPO / "benchmarks" / bench).read_text()


def test_a_runs_scratch_is_under_the_batch_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[Path] = []
    real = run_mod.build

    def spy(sc, seed, workdir, *a, **kw):  # noqa: ANN001, ANN002, ANN003, ANN202
        seen.append(Path(workdir))
        return real(sc, seed, workdir, *a, **kw)

    monkeypatch.setattr(run_mod, "build", spy)
    sc, raw = load(GAUSS)
    spec = expand(sc, raw, str(GAUSS), 1, out_dir=str(tmp_path / "b"))[0]
    assert run_mod.execute(spec)["status"] == "ok"
    assert seen and seen[0].parent.resolve() == (tmp_path / "b" / ".tmp").resolve()
    assert not seen[0].exists()  # removed when the run ends


def test_resume_removes_the_scratch_of_killed_runs(tmp_path: Path) -> None:
    out = tmp_path / "o"
    args = [str(GAUSS), "--out", str(out), "--quiet", "--no-report", "--workers", "1"]
    assert main(args) == 0
    stale = out / ".tmp" / "corridor-killed"
    stale.mkdir(parents=True)
    assert main([*args, "--runs", "2", "--resume"]) == 0
    assert not stale.exists()


def test_a_uav_batch_leaves_nothing_in_the_system_temp_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Forked runners skip atexit: the JSBSim aircraft folder was one corridor-jsbsim-* per worker."""
    sys_tmp, cache = tmp_path / "systmp", tmp_path / "cache"
    sys_tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(sys_tmp))
    monkeypatch.setenv("CORRIDOR_CACHE", str(cache))
    out = tmp_path / "uav"
    assert main([str(SCENARIOS / "uav_encounter.yaml"), "--runs", "2", "--workers", "2", "--out", str(out),
                 "--set", "duration=1", "--variant", "none", "--quiet", "--no-report"]) == 0
    assert sorted(os.listdir(sys_tmp)) == []
    assert len(list((cache / "jsbsim").glob("aircraft-*"))) == 1  # one shared folder, reused
