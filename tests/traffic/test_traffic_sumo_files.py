"""A user's own SUMO network (``road.network.type: sumo_files``) and SUMO's own outputs.

The network is held out: generated here by SUMO's ``netgenerate`` (a spider network, not in the
repository) with demand from SUMO's ``randomTrips.py`` plus a hand-written route file, then run
through ``run_scenario`` as a short batch.  Bad inputs are one line and exit code 2.
"""

from __future__ import annotations

import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import sumolib

from corridor.api import run
from corridor.cli import main
from corridor.traffic.networks.registry import netconvert_binary
from tests.conftest import SCENARIOS

DURATION_S = 150.0


def _sumo_tool(name: str) -> Path:
    import sumo

    return Path(sumo.SUMO_HOME) / "tools" / name


@pytest.fixture(scope="module", autouse=True)
def _own_cache(tmp_path_factory):
    """The copies of these throw-away networks go to a temporary cache, not the user's."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CORRIDOR_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def own(tmp_path_factory) -> Path:
    """A folder ``net/`` with a generated network, its routes, an extra route file and a sumocfg."""
    root = tmp_path_factory.mktemp("own")
    net_dir = root / "net"
    net_dir.mkdir()
    netgenerate = netconvert_binary().with_name("netgenerate")
    subprocess.run([str(netgenerate), "--spider", "--spider.arm-number", "5", "--spider.circle-number", "3",
                    "--spider.space-radius", "90", "--default.lanenumber", "2", "--default.speed", "13.9",
                    "--tls.guess", "true", "--seed", "11", "-o", str(net_dir / "spider.net.xml")],
                   check=True, capture_output=True)
    subprocess.run([sys.executable, str(_sumo_tool("randomTrips.py")), "-n", str(net_dir / "spider.net.xml"),
                    "-o", str(net_dir / "trips.xml"), "--route-file", str(net_dir / "spider.rou.xml"),
                    "-e", "120", "-p", "1.2", "--seed", "5", "--validate", "--fringe-factor", "5"],
                   check=True, capture_output=True, cwd=net_dir)
    # a named route through the network (the first randomTrips vehicle's) for a corridor flow
    first = ET.parse(net_dir / "spider.rou.xml").getroot().find("vehicle/route")
    (net_dir / "extra.rou.xml").write_text(
        '<routes>\n    <vType id="truck" length="12" maxSpeed="22" accel="1.2" decel="4"/>\n'
        f'    <route id="through" edges="{first.get("edges")}"/>\n'
        '    <vehicle id="truck0" type="truck" route="through" depart="5"/>\n</routes>\n')
    (net_dir / "own.sumocfg").write_text(
        '<configuration>\n  <input>\n    <net-file value="spider.net.xml"/>\n'
        '    <route-files value="spider.rou.xml"/>\n  </input>\n  <time><end value="3600"/></time>\n'
        '</configuration>\n')
    return root


def _scenario(root: Path, name: str, network: str, extra: str = "") -> Path:
    """A scenario in ``root/scen/`` (one folder below the files: paths are relative to the scenario)."""
    folder = root / "scen"
    folder.mkdir(exist_ok=True)
    path = folder / f"{name}.yaml"
    path.write_text(f"""name: {name}
duration: {DURATION_S}
warmup: 10
road:
  network: {network}
{extra}""")
    return path


NET_ROUTES = "{type: sumo_files, params: {net: ../net/spider.net.xml, routes: [../net/spider.rou.xml, ../net/extra.rou.xml]}}"
MONITORS = """monitors:
  ssm: {type: surrogate_safety}
  kpis: {type: traffic_kpis, params: {count_landmark: null}}
"""


def test_own_network_runs_with_safety_metrics_and_sumo_outputs(own, tmp_path):
    sc = _scenario(own, "own_net", NET_ROUTES, """  demand: {flows: {extra: {route: through, flow_vph: 240}}}
  sumo: {outputs: [fcd, tripinfo, summary, ssm]}
""" + MONITORS)
    res = run(sc, runs=2, out=tmp_path / "out", workers=1, report=False)
    df = res.rows
    assert list(df["status"]) == ["ok", "ok"], df.get("error")
    for _, r in df.iterrows():
        assert r["collisions"] >= 0
        assert 0.0 < r["min_ttc_s"] <= 99.0 and r["max_drac_mps2"] >= 0.0 and r["hard_brakes"] >= 0
        assert r["vehicles_departed"] > 50  # ~100 randomTrips vehicles, the truck, the corridor flow
        assert 0 < r["vehicles_arrived"] <= r["vehicles_departed"]
        assert 0.0 < r["delay_mean_s"] < DURATION_S and math.isfinite(r["tts_vh"])
        assert r["throughput_vph"] > 0
        files = res.out / "sumo" / r["run_id"]
        fcd = ET.parse(files / "fcd.xml").getroot()
        seen = {v.get("id") for step in fcd.iter("timestep") for v in step.iter("vehicle")}
        assert "truck0" in seen and any(v.startswith("extra.") for v in seen) and any(v.isdigit() for v in seen)
        trips = ET.parse(files / "tripinfo.xml").getroot().findall("tripinfo")
        assert len(trips) == r["vehicles_arrived"]  # SUMO's own count of finished trips is the row's
        after_warmup = sum(float(t.get("arrival")) >= 10.0 for t in trips)  # throughput: arrivals after it
        assert r["throughput_vph"] == pytest.approx(after_warmup * 3600.0 / (DURATION_S - 10.0))
        steps = ET.parse(files / "summary.xml").getroot().findall("step")
        assert max(int(s.get("inserted")) for s in steps) == r["vehicles_departed"]
        assert ET.parse(files / "ssm.xml").getroot().tag == "SSMLog"
    assert df["vehicles_departed"].nunique() == 2 or df["delay_mean_s"].nunique() == 2  # seeds differ
    truck = ET.parse(res.out / "sumo" / df["run_id"][0] / "tripinfo.xml").getroot().find("tripinfo[@id='truck0']")
    assert truck is not None and truck.get("vType") == "truck"


def test_sumocfg_gives_the_rows_of_its_files(own, tmp_path):
    cfg = _scenario(own, "own_cfg", "{type: sumo_files, params: {sumocfg: ../net/own.sumocfg}}", MONITORS)
    files = _scenario(own, "own_files", "{type: sumo_files, params: {net: ../net/spider.net.xml, "
                      "routes: ../net/spider.rou.xml}}", MONITORS)
    res = run(cfg, runs=1, seed=3, out=tmp_path / "a", workers=1, report=True)
    a = res.rows
    b = run(files, runs=1, seed=3, out=tmp_path / "b", workers=1, report=False).rows
    assert a["status"][0] == "ok" and a["vehicles_departed"][0] > 50
    assert (res.out / "report.html").stat().st_size > 10_000  # the report re-reads the scenario's params
    for col in ("vehicles_departed", "vehicles_arrived", "delay_mean_s", "min_ttc_s", "collisions", "tts_vh"):
        assert a[col][0] == b[col][0], col


def test_own_network_lanes_match_the_file(own):
    """The road frame's lanes are the network's: landmarks measured on the file."""
    from corridor.traffic.networks.registry import build_network

    params = {"net": str(own / "net" / "spider.net.xml"), "routes": [str(own / "net" / "extra.rou.xml")]}
    built = build_network("sumo_files", params)
    net = sumolib.net.readNet(str(own / "net" / "spider.net.xml"))
    assert built.landmarks.edges == len(net.getEdges())
    assert built.landmarks.lanes == sum(len(e.getLanes()) for e in net.getEdges())
    assert built.routes["through"] and built.route_files and built.route_files[0].exists()


def test_additional_files_write_nothing_outside_the_batch_folder(own, tmp_path):
    """A detector of the user's additional file names an output beside the scenario: SUMO writes
    nowhere but the batch folder (the copy's ``file`` is NUL), and the run still counts its vehicles."""
    first = ET.parse(own / "net" / "spider.rou.xml").getroot().find("vehicle/route").get("edges").split()
    (own / "net" / "det.add.xml").write_text(
        f'<additional>\n    <route id="side" edges="{" ".join(first)}"/>\n'
        f'    <inductionLoop id="loop0" lane="{first[0]}_0" pos="5" period="30" file="../escaped_e1.xml"/>\n'
        '    <edgeData id="ed" period="60" file="/tmp/escaped_edgedata.xml"/>\n</additional>\n')
    sc = _scenario(own, "own_add", "{type: sumo_files, params: {net: ../net/spider.net.xml, "
                   "additional: [../net/det.add.xml]}}",
                   "  demand: {flows: {side: {route: side, flow_vph: 900, arrivals: uniform}}}\n"
                   "  sumo: {outputs: [tripinfo]}\nmonitors:\n  kpis: {type: traffic_kpis, params: {count_landmark: null}}\n")
    res = run(sc, runs=1, out=tmp_path / "out", workers=1, report=False)
    row = res.rows.iloc[0]
    assert row["status"] == "ok", row["error"]
    # 900 veh/h, evenly spaced, on the additional file's route for 150 s: inserted or waiting at the end
    assert row["vehicles_departed"] + row["insertion_backlog"] == round(900 * 150 / 3600) and row["vehicles_departed"] >= 20
    assert not (own / "escaped_e1.xml").exists() and not (own / "net" / "escaped_e1.xml").exists()
    assert not Path("/tmp/escaped_edgedata.xml").exists()
    written = sorted(p.relative_to(res.out).as_posix() for p in res.out.rglob("*.xml"))
    assert written == [f"sumo/{row['run_id']}/tripinfo.xml"]


def test_routes_with_errors_run_with_sumos_own_option(own, tmp_path):
    """A route with a gap (common in routes made for an older OSM extract) fails the run in SUMO;
    ``--ignore-route-errors`` (allowed in road.sumo.extra_args: it writes no file) lets it run."""
    routes = ET.parse(own / "net" / "spider.rou.xml").getroot().findall("vehicle/route")
    good, a, b = routes[0].get("edges"), routes[0].get("edges").split()[0], routes[1].get("edges").split()[-1]
    assert b not in {e.getID() for e in sumolib.net.readNet(str(own / "net" / "spider.net.xml")).getEdge(a).getOutgoing()}
    (own / "net" / "gap.rou.xml").write_text(
        f'<routes>\n    <vehicle id="ok0" depart="0"><route edges="{good}"/></vehicle>\n'
        f'    <vehicle id="gap0" depart="1"><route edges="{a} {b}"/></vehicle>\n</routes>\n')
    net = "{type: sumo_files, params: {net: ../net/spider.net.xml, routes: ../net/gap.rou.xml}}"
    strict = run(_scenario(own, "gap", net), out=tmp_path / "a", workers=1, report=False).rows.iloc[0]
    assert strict["status"] == "error" and "'gap0' has no valid route" in strict["error"]
    lenient = _scenario(own, "gap_ok", net, "  sumo: {extra_args: [--ignore-route-errors, 'true']}\n")
    row = run(lenient, out=tmp_path / "b", workers=1, report=False).rows.iloc[0]
    assert row["status"] == "ok" and row["vehicles_departed"] >= 1


def _tiny_osm(path: Path) -> Path:
    """An OpenStreetMap extract as the OSM API writes it: a 3 x 3 grid of two-way streets, ~150 m
    blocks around 48.137 N, 11.575 E (the middle one a secondary road)."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="corridor-test">']
    for i in range(3):
        for j in range(3):
            lines.append(f'  <node id="{1 + 3 * i + j}" lat="{48.137 + i * 0.00135:.6f}" '
                         f'lon="{11.575 + j * 0.002:.6f}" version="1" visible="true"/>')
    rows = [[1 + 3 * i + j for j in range(3)] for i in range(3)]
    for w, (nodes, kind) in enumerate([*((r, "secondary" if k == 1 else "residential") for k, r in enumerate(rows)),
                                       *((list(c), "residential") for c in zip(*rows, strict=True))]):
        lines += [f'  <way id="{100 + w}" version="1" visible="true">', *(f'    <nd ref="{n}"/>' for n in nodes),
                  f'    <tag k="highway" v="{kind}"/>', '    <tag k="maxspeed" v="50"/>', "  </way>"]
    path.write_text("\n".join([*lines, "</osm>"]) + "\n")
    return path


def test_an_osm_derived_network_runs_as_the_guide_says(tmp_path):
    """docs/guide/own-network.md, step 1 and 2: netconvert --osm-files (the guide's options),
    randomTrips, the YAML beside the files."""
    osm = _tiny_osm(tmp_path / "town.osm")
    subprocess.run([str(netconvert_binary()), "--osm-files", str(osm), "-o", str(tmp_path / "town.net.xml"),
                    "--geometry.remove", "--ramps.guess", "--junctions.join", "--tls.guess-signals", "--tls.join",
                    "--remove-edges.by-vclass", "pedestrian,bicycle", "--keep-edges.by-vclass", "passenger"],
                   check=True, capture_output=True)
    subprocess.run([sys.executable, str(_sumo_tool("randomTrips.py")), "-n", "town.net.xml", "-o", "town.trips.xml",
                    "--route-file", "town.rou.xml", "-e", "120", "-p", "3", "--validate", "--seed", "42"],
                   check=True, capture_output=True, cwd=tmp_path)
    (tmp_path / "my_town.yaml").write_text(
        "name: my_town\nduration: 150\nwarmup: 10\nroad:\n  network:\n    type: sumo_files\n"
        "    params: {net: town.net.xml, routes: [town.rou.xml]}\n  sumo: {outputs: [fcd]}\n" + MONITORS)
    row = run(tmp_path / "my_town.yaml", out=tmp_path / "out", workers=1, report=False).rows.iloc[0]
    assert row["status"] == "ok", row["error"]
    assert row["vehicles_departed"] >= 30 and row["vehicles_arrived"] > 0 and row["delay_mean_s"] > 0
    fcd = ET.parse(tmp_path / "out" / "sumo" / row["run_id"] / "fcd.xml").getroot()
    assert len({v.get("id") for v in fcd.iter("vehicle")}) == row["vehicles_departed"]


def test_sumo_outputs_are_observers_on_any_road_scenario(tmp_path):
    """SUMO's own outputs on a generated network (merging.yaml): the files are written per run and
    the rows are those of the same runs without them (writing files changes no trajectory)."""
    common = ["duration=40", "warmup=0"]
    merging = SCENARIOS / "merging.yaml"
    plain = run(merging, sets=common, variants=["sumo_default"], out=tmp_path / "plain", workers=1, report=False)
    res = run(merging, sets=[*common, "road.sumo.outputs=[fcd, tripinfo, summary, ssm]"], variants=["sumo_default"],
              out=tmp_path / "out", workers=1, report=False)
    a, b = plain.rows.iloc[0], res.rows.iloc[0]
    assert b["status"] == "ok", b["error"]
    volatile = {c for c in a.index if "wall" in c or "time_s" in c or c == "traceback"}
    for col in sorted(set(a.index) - volatile):
        assert (a[col] == b[col]) or (a[col] != a[col] and b[col] != b[col]), col  # NaN == NaN
    files = sorted(p.name for p in (res.out / "sumo" / b["run_id"]).iterdir())
    assert files == ["fcd.xml", "ssm.xml", "summary.xml", "tripinfo.xml"]


def test_resume_after_the_network_changed_is_refused(own, tmp_path, capsys):
    """The batch folder records the files the scenario names: rows of two versions never mix."""
    net = tmp_path / "n.net.xml"
    net.write_bytes((own / "net" / "spider.net.xml").read_bytes())
    (tmp_path / "r.yaml").write_text(f"name: r\nduration: 20\nroad:\n  network: {{type: sumo_files, params: "
                                     f"{{net: n.net.xml, routes: [{own / 'net' / 'spider.rou.xml'}]}}}}\n")
    out = tmp_path / "out"
    argv = [str(tmp_path / "r.yaml"), "--out", str(out), "--no-report", "--quiet", "--workers", "1"]
    assert main(argv) == 0
    assert main([*argv, "--resume", "--runs", "2"]) == 0  # unchanged files: resumed
    capsys.readouterr()
    net.write_bytes(net.read_bytes().replace(b'speed="13.89"', b'speed="8.00"', 1))  # an edited network
    err = _one_line_exit_2(capsys, *argv, "--resume", "--runs", "3")
    assert f"{net.name}' changed since the batch started" in err  # the path's start may be cut, never its name


def _one_line_exit_2(capsys, *argv: str) -> str:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize(("name", "network", "extra", "expect"), [
    ("missing_net", "{type: sumo_files, params: {net: ../net/nope.net.xml}}",
     "  demand: {flows: {a: {route: x, flow_vph: 1}}}\n", "road.network.params.net: no such file: '../net/nope.net.xml'"),
    ("missing_route", "{type: sumo_files, params: {net: ../net/spider.net.xml, routes: [nope.rou.xml]}}", "",
     "road.network.params.routes.0: no such file"),
    ("a_folder", "{type: sumo_files, params: {net: ../net}}", "  demand: {flows: {a: {route: x, flow_vph: 1}}}\n",
     "road.network.params.net: not a regular file: '../net'"),
    ("a_device", "{type: sumo_files, params: {net: /dev/zero}}", "  demand: {flows: {a: {route: x, flow_vph: 1}}}\n",
     "road.network.params.net: not a regular file: '/dev/zero'"),
    ("empty_path", "{type: sumo_files, params: {net: ''}}", "  demand: {flows: {a: {route: x, flow_vph: 1}}}\n",
     "road.network.params.net: '' is not a file path"),
    ("cwd_relative", "{type: sumo_files, params: {net: net/spider.net.xml, routes: [net/spider.rou.xml]}}", "",
     "relative to the scenario's folder"),
    ("routes_as_net", "{type: sumo_files, params: {net: ../net/spider.rou.xml}}",
     "  demand: {flows: {a: {route: x, flow_vph: 1}}}\n", "root element <routes>, a SUMO net file has <net>"),
    ("no_demand", "{type: sumo_files, params: {net: ../net/spider.net.xml}}", "",
     "road: the network has no route files"),
    ("both", "{type: sumo_files, params: {net: ../net/spider.net.xml, sumocfg: ../net/own.sumocfg}}", "",
     "give exactly one of net"),
    ("unknown_output", NET_ROUTES, "  sumo: {outputs: [fcd, emissions]}\n", "road.sumo.outputs.1"),
    ("output_path", NET_ROUTES, "  sumo: {outputs: [../../../fcd.xml]}\n", "road.sumo.outputs.0"),
    ("output_mapping", NET_ROUTES, "  sumo: {outputs: {fcd: /tmp/fcd.xml}}\n", "road.sumo.outputs"),
    ("output_option", NET_ROUTES, "  sumo: {extra_args: [--fcd-output, ../fcd.xml]}\n", "writes files"),
    ("merging", NET_ROUTES, "controllers:\n  merge: {type: v2x_merging}\n",
     "controllers.merge: V2X merging needs the landmarks of a highway_onramp network (upstream_edge"),
    ("ramp_metering", NET_ROUTES, "controllers:\n  ramps: {type: ramp_alinea}\n",
     "controllers.ramps: ramp metering needs the landmarks of a beltway network"),
    ("kpi_line", NET_ROUTES, "monitors:\n  kpis: {type: traffic_kpis}\n", "count_landmark"),
])
def test_bad_own_network_is_one_line_exit_2(own, tmp_path, capsys, name, network, extra, expect):
    sc = _scenario(own, f"bad_{name}", network, extra)
    out = tmp_path / "out"
    err = _one_line_exit_2(capsys, str(sc), "--out", str(out), "--runs", "1", "--no-report", "--quiet")
    assert expect in err, err
    assert not out.exists()  # refused before the batch folder is touched


def test_bad_sumocfg_input_is_one_line(own, tmp_path, capsys):
    (own / "net" / "bad.sumocfg").write_text('<configuration><input><net-file value="spider.net.xml"/>'
                                             '<route-files value="gone.rou.xml"/></input></configuration>')
    sc = _scenario(own, "bad_cfg", "{type: sumo_files, params: {sumocfg: ../net/bad.sumocfg}}")
    err = _one_line_exit_2(capsys, str(sc), "--out", str(tmp_path / "out"), "--no-report", "--quiet")
    assert "route-files 'gone.rou.xml': no such file" in err


def test_merging_on_a_network_without_a_merge_is_refused_at_load(tmp_path, capsys):
    """Before: accepted at load, then every run an error row ('V2X merging needs an on-ramp network')."""
    sc = tmp_path / "m.yaml"
    sc.write_text("name: m\nduration: 5\nroad:\n  network: {type: rural_two_lane}\n"
                  "  demand: {flows: {e: {route: east, flow_vph: 100}}}\ncontrollers:\n  merge: {type: v2x_merging}\n")
    err = _one_line_exit_2(capsys, str(sc), "--out", str(tmp_path / "out"), "--no-report", "--quiet")
    assert "needs the landmarks of a highway_onramp network" in err and "'rural_two_lane' has none" in err
