"""Flow's merge network (``flow_merge``), the driver presets, and the measurements of issue 27 on a real
SUMO run: virtual loops count every vehicle that passes, emissions are SUMO's own."""

from __future__ import annotations

import math
import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import sumolib
from pydantic import ValidationError

from corridor.traffic.networks.registry import build_network
from corridor.traffic.sumo.backend import vtype_attrs
from corridor.traffic.sumo.driver_presets import PRESETS
from corridor.traffic.sumo.road_spec import VehicleTypeSpec

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "flow_merge.yaml"


def test_flow_merge_network_has_flows_lengths_and_junction(tmp_path: Path) -> None:
    net = build_network("flow_merge", {}, tmp_path)
    sn = sumolib.net.readNet(str(net.net_file), withInternal=True)
    lm = net.landmarks
    # Flow's edges: 100 m inflows; the 500 m pre-merge, 100 m merge and 100 m post-merge edges lose the
    # junction's 10 m radius (netconvert trims them; Flow's own edge starts show the same 22.6 m junction)
    assert sn.getLane("inflow_highway_0").getLength() == pytest.approx(100.0, abs=0.1)
    assert sn.getLane("inflow_merge_0").getLength() == pytest.approx(100.0, abs=0.1)
    assert 480 < sn.getLane("left_0").getLength() <= 500
    assert 80 < sn.getLane("bottom_0").getLength() <= 100
    assert 80 < sn.getLane("center_0").getLength() <= 100
    assert all(sn.getLane(f"{e}_0").getSpeed() == 30.0 for e in ("left", "center", "bottom"))
    assert net.routes == {"main": ("inflow_highway", "left", "center"), "ramp": ("inflow_merge", "bottom", "center")}
    assert lm.mainline_start_x == 0.0 and lm.mainline_end_x == pytest.approx(700.0)
    assert lm.merge_x < 600.0 < lm.past_merge_x
    # the highway has the right of way at the junction (netconvert gives it to the ramp when equal)
    assert sn.getEdge("left").getConnections(sn.getEdge("center"))[0].getState() == "M"
    assert sn.getEdge("bottom").getConnections(sn.getEdge("center"))[0].getState() == "m"
    assert lm.is_ramp_lane("inflow_merge_0") and lm.is_ramp_lane("bottom_0") and not lm.is_ramp_lane("left_0")


def test_a_preset_fills_a_vehicle_type_and_given_fields_override_it() -> None:
    vt = VehicleTypeSpec.model_validate({"preset": "flow_human", "tau": 1.5, "extra": {"emissionClass": "Zero"}})
    assert vt.car_following == "IDM" and vt.accel == 2.6 and vt.tau == 1.5 and vt.speed_mode == 1
    assert vt.extra == {"impatience": 0.5, "emissionClass": "Zero"}  # merged key by key
    attrs = vtype_attrs(vt)
    assert attrs["carFollowModel"] == "IDM" and attrs["impatience"] == 0.5 and "preset" not in attrs
    with pytest.raises(ValidationError, match="unknown driver preset 'nope'; known: .*sumo_default"):
        VehicleTypeSpec.model_validate({"preset": "nope"})


def test_the_sumo_default_preset_is_sumos_own_passenger_car() -> None:
    vt = VehicleTypeSpec.model_validate({"preset": "sumo_default"})
    assert (vt.car_following, vt.accel, vt.decel, vt.sigma, vt.tau, vt.min_gap, vt.length) == (
        "Krauss", 2.6, 4.5, 0.5, 1.0, 2.5, 5.0)
    assert vt.lc == {} and set(PRESETS) >= {"sumo_default", "flow_human"}


def _short_run() -> dict[str, object]:
    from corridor.run import build
    from corridor.scenario import load

    sc, _ = load(str(SCENARIO), ["duration=200"])
    sim = build(sc, 1, Path(tempfile.mkdtemp()))
    ctx = sim.ctx
    for c in ctx.components.values():
        c.setup(ctx)
    try:
        ls = ctx.components["road"].libsumo  # the test compares with SUMO's own figures
        co2_sumo = fuel_sumo = 0.0
        for _ in range(round(sc.duration / sc.dt)):
            sim.step()
            ids = ls.vehicle.getIDList()
            co2_sumo += sum(ls.vehicle.getCO2Emission(v) for v in ids) * sc.dt
            fuel_sumo += sum(ls.vehicle.getFuelConsumption(v) for v in ids) * sc.dt
        loops, network = ctx.components["loops"], ctx.components["network"]
        road = ctx.snapshot.road
        x = ctx.snapshot.position[road.sl, 0]
        down_x = float(loops.line_x[loops.names.index("down")])
        beyond = int(np.count_nonzero(x >= down_x))
        metrics = network.finish(ctx)
        k = loops.names.index("down")  # closed intervals, plus the one still open
        counted = float(np.sum(np.array(loops.flow)[:, k]) * loops.p.interval_s / 3600 + loops._count[k])
        return {"down_count": counted,
                "arrived": ls.simulation.getArrivedNumber(), "beyond": beyond,
                "arrived_total": network.arrived, "co2_kg": metrics["co2_total_kg"], "co2_sumo_kg": co2_sumo / 1e6,
                "fuel_sumo_mg": fuel_sumo, "fuel_g_per_km": metrics["fuel_g_per_km"], "t": ctx.t}
    finally:
        for c in ctx.components.values():
            c.close()


def test_loops_count_every_vehicle_past_them_and_emissions_are_sumos() -> None:
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        out = pool.submit(_short_run).result()
    # every vehicle that passed the downstream loop has arrived or is still beyond it (conservation)
    assert out["down_count"] == out["arrived_total"] + out["beyond"]
    assert out["down_count"] > 80  # ~175 s of ~2100 veh/h past the loop
    assert math.isclose(out["co2_kg"], out["co2_sumo_kg"], rel_tol=1e-9)
    assert out["fuel_g_per_km"] > 0
