"""The UAV scenarios end to end through ``run_scenario``: rows ok, the encounters are real conflicts
(``none`` has NMACs), both avoidance methods keep every pair out of the NMAC cylinder, and the
MAVLink bytes a run writes decode with pymavlink's own parser."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from tests.conftest import REPO, SCENARIOS

ENCOUNTER = SCENARIOS / "uav_encounter.yaml"
SWARM = SCENARIOS / "uav_swarm.yaml"


def cli(*args: str) -> pd.DataFrame:
    out = Path(args[args.index("--out") + 1])
    exe = [sys.executable, "-m", "corridor.cli", *args, "--quiet", "--no-report"]
    res = subprocess.run(exe, capture_output=True, text=True, cwd=REPO, timeout=1800)
    assert res.returncode == 0, res.stderr[-2000:]
    return pd.read_parquet(out / "runs.parquet")


def check_variants(df: pd.DataFrame) -> None:
    assert (df["status"] == "ok").all(), df[df["status"] != "ok"]["error"].tolist()
    none = df[df["variant"] == "none"]
    assert (none["nmac"] >= 1).all(), none[["run_id", "nmac", "sep_min_h_m"]]
    for v in ("potential_field", "control_tube"):
        g = df[df["variant"] == v]
        assert len(g) and (g["nmac"] == 0).all() and (g["collisions"] == 0).all(), g[["run_id", "nmac", "sep_min_3d_m"]]


def test_short_head_on_encounter_all_variants(tmp_path: Path) -> None:
    # seed 10 draws the head-on geometry (alt offset 0.2 m, heading offset 6.7 deg); a short approach
    # (10 s) and no c172 keep the runs short
    df = cli(str(ENCOUNTER), "--runs", "1", "--seed", "10", "--workers", "2", "--out", str(tmp_path / "e"),
             "--set", "duration=30", "--set", "backends.air.params.encounter.time_to_conflict_s=10",
             "--set", "backends.air.params.encounter.piloted=false")
    assert (df["draw.backends.air.params.encounter.geometry"] == 0).all()  # common random numbers
    assert set(df["variant"]) == {"none", "potential_field", "control_tube"}
    check_variants(df)
    # the link ran: 5 % Bernoulli loss -> delivery ratio ~0.95; nothing corrupted on a clean channel
    assert df["link_delivery_ratio"].between(0.92, 0.98).all()
    assert (df["mavlink_bad_crc"] == 0).all() and (df["mavlink_messages"] > 300).all()
    # the run's real-time factor is in every row (a measurement of the machine: only its presence is checked)
    assert (df["rtf"].notna() & (df["rtf"] > 0.0)).all()


def test_control_tube_passes_below_the_phugoiding_c172x(tmp_path: Path) -> None:
    """Plain run 5076 of the rare-event study (degraded link, crossing geometry, the c172x 22 m above
    the conflict point at 15 s): UAV b used to climb over the c172x, which climbed through its phugoid
    and passed 11.8 m under it. With the vertical side taken from the measured altitudes it descends."""
    df = cli(str(ENCOUNTER), "--variant", "control_tube", "--seed", "5076", "--out", str(tmp_path / "e"),
             "--set", "channels.mavlink.loss.p=0.3", "--set", "channels.mavlink.latency_s=0.3",
             "--set", "duration=25")
    assert df["draw.backends.air.params.encounter.geometry"].tolist() == [1]
    assert 21.9 < df["draw.backends.air.params.encounter.piloted_alt_offset_m"].iloc[0] < 22.0
    assert df["status"].tolist() == ["ok"] and df["sep_min_3d_m"].iloc[0] > 35.0


@pytest.mark.slow
def test_encounter_every_geometry_several_seeds(tmp_path: Path) -> None:
    df = cli(str(ENCOUNTER), "--runs", "5", "--seed", "4", "--workers", "2", "--out", str(tmp_path / "e"),
             "--set", "duration=45")  # seeds 4-8 draw geometries 1, 2, 0, 1, 0
    assert set(df["draw.backends.air.params.encounter.geometry"]) == {0, 1, 2}
    check_variants(df)


@pytest.mark.slow
def test_small_swarm_swaps_positions(tmp_path: Path) -> None:
    df = cli(str(SWARM), "--runs", "1", "--workers", "2", "--out", str(tmp_path / "s"),
             "--set", "backends.air.params.swarm.n=8", "--set", "backends.air.params.swarm.radius_m=100",
             "--set", "duration=60")
    check_variants(df)
    # without avoidance every UAV flies its straight diameter (path ratio 1) through the centre
    none = df[df["variant"] == "none"].iloc[0]
    assert none["goal_reached_frac"] == 1.0 and none["path_ratio_max"] == pytest.approx(1.0, abs=0.01)
    assert none["nmac"] >= 8  # at least every neighbour pair meets inside the cylinder


def test_mavlink_bytes_decode_with_pymavlink_and_rerun_shows_aircraft(tmp_path: Path) -> None:
    from pymavlink.dialects.v20 import common as mavlink2
    from rerun.chunk import RrdReader

    # the log path is relative to the output folder; the run id is added to the file name
    log, rrd = tmp_path / "m" / "mavlink" / "link-none-s0.bin", tmp_path / "enc.rrd"
    df = cli(str(ENCOUNTER), "--runs", "1", "--variant", "none", "--out", str(tmp_path / "m"),
             "--set", "duration=3", "--set", "backends.link.params.log_path=mavlink/link.bin", "--rerun", str(rrd))
    paths = {c.entity_path for c in RrdReader(rrd).stream()}
    assert {"/world/entities", "/world/trails", "/metrics/min_sep_h", "/metrics/min_sep_3d"} <= paths
    assert {"/world/air_markers", "/world/ground"} <= paths  # fixed-size markers, a grid at the origin
    assert (df["status"] == "ok").all()
    parser = mavlink2.MAVLink(None)
    msgs = parser.parse_buffer(log.read_bytes()) or []
    kinds = pd.Series([m.get_type() for m in msgs]).value_counts()
    # 3 s at 10 Hz; the first link tick (t = 0) precedes the first snapshot, so 29 position epochs:
    # 2 UAVs x 29 x (GLOBAL_POSITION_INT + LOCAL_POSITION_NED), 29 ADSB_VEHICLE, 1 Hz heartbeats
    assert kinds["LOCAL_POSITION_NED"] == 58 and kinds["GLOBAL_POSITION_INT"] == 58
    assert kinds["ADSB_VEHICLE"] == 29 and kinds["HEARTBEAT"] >= 6
    assert "BAD_DATA" not in kinds and int(df["mavlink_sent_datagrams"].iloc[0]) > 0
