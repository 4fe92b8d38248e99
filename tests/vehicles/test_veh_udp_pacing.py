"""The MAVLink UDP mirror can be paced to wall-clock time: a paced run never finishes before its
simulated duration has passed, and a socket on 127.0.0.1 receives valid MAVLink 2 frames."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from corridor.cli import main
from corridor.run import simulate
from corridor.scenario import load
from tests.conftest import SCENARIOS

ENCOUNTER = SCENARIOS / "uav_encounter.yaml"


def _receiver() -> tuple[socket.socket, int]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    return rx, rx.getsockname()[1]


def _drain(rx: socket.socket) -> list[bytes]:
    rx.settimeout(0.5)
    out = []
    try:
        while True:
            out.append(rx.recv(65536))
    except TimeoutError:
        return out


@pytest.mark.parametrize("factor", [1.0, 2.0])
def test_paced_mirror_runs_no_faster_than_wall_time_and_sends_mavlink2(factor):
    rx, port = _receiver()
    try:
        duration = 0.5
        sc, _ = load(ENCOUNTER, [f"duration={duration}", "controllers.avoid.type=uav_none",
                                 f"backends.link.params.udp_mirror=udpout:127.0.0.1:{port}",
                                 f"backends.link.params.realtime_factor={factor}"])
        t0 = time.perf_counter()
        metrics, _, wall_s = simulate(sc, 0)
        elapsed = time.perf_counter() - t0
        datagrams = _drain(rx)
    finally:
        rx.close()
    assert wall_s >= duration / factor and elapsed >= duration / factor
    assert metrics["link_paced_sleep_s"] > 0.0
    assert datagrams and all(d[0] == mavlink2.PROTOCOL_MARKER_V2 for d in datagrams)
    parser = mavlink2.MAVLink(None)  # raises on a bad CRC
    kinds = {m.get_type() for d in datagrams for m in (parser.parse_buffer(d) or [])}
    assert {"HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ADSB_VEHICLE"} <= kinds
    assert len(datagrams) == metrics["mavlink_sent_datagrams"]


def test_pacing_without_mirror_is_refused_in_one_line(capsys, tmp_path):
    code = main([str(ENCOUNTER), "--out", str(tmp_path / "o"), "--set", "backends.link.params.realtime_factor=1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "backends.link.params" in err and "udp_mirror" in err
