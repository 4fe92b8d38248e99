"""The report's verdict counts every safety event the scenario measures (collisions, NMAC, LoS,
pair-class events, spec violations), per variant: never a green "no run ..." over an NMAC."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from corridor.analysis.glossary import safety_event_columns
from corridor.analysis.report import write_report
from corridor.scenario import load
from tests.conftest import SCENARIOS


def _uav_rows(nmac_none: int) -> pd.DataFrame:
    rows = []
    for s in range(2):
        for v in ("none", "potential_field", "control_tube"):
            nmac = nmac_none if (v == "none" and s == 1) else 0
            rows.append({"run_id": f"{v}-s{s}", "variant": v, "seed": s, "status": "ok", "error": "",
                         "collisions": 0, "nmac": nmac, "los": nmac, "nmac_pairs": nmac,
                         "sep_min_h_m": 2.4 if nmac else 150.0, "sep_min_3d_m": 3.0 if nmac else 160.0})
    return pd.DataFrame(rows)


def _verdict(text: str) -> str:
    return text.split("<h2>Verdict")[1].split("<h2>")[0]


def test_uav_nmac_is_not_reported_as_a_clean_batch(tmp_path: Path) -> None:
    sc = load(SCENARIOS / "uav_encounter.yaml", [])[0]
    assert {"collisions", "nmac", "los", "nmac_pairs"} <= set(safety_event_columns(_uav_rows(1).columns, sc))
    verdict = _verdict(write_report(_uav_rows(1), sc, tmp_path / "r.html").read_text())
    assert "No run" not in verdict and "class=good>No" not in verdict
    assert "none-s1" in verdict and "1 nmac" in verdict and "1 los" in verdict
    row = next(r for r in verdict.split("<tr>") if r.startswith("<td>none</td>"))
    assert "<td class=bad>1/2 (1)</td>" in row  # runs with an NMAC / runs, total NMACs
    clean = _verdict(write_report(_uav_rows(0), sc, tmp_path / "c.html").read_text())
    assert "class=good>No run failed, had a safety event (collisions, nmac, los, nmac_pairs" in clean


def test_pair_class_events_and_spec_violations_count(tmp_path: Path) -> None:
    sc = load(SCENARIOS / "air_ground_watch.yaml", [])[0]
    df = pd.DataFrame({"run_id": ["a-s0", "a-s1"], "variant": ["a", "a"], "seed": [0, 1], "status": ["ok", "ok"],
                       "error": ["", ""], "collisions": [0, 0], "nmac_uav_aircraft": [0, 2],
                       "spec.keep_apart.satisfied": [False, True]})
    assert "nmac_uav_aircraft" in safety_event_columns(df.columns, sc)
    verdict = _verdict(write_report(df, sc, tmp_path / "r.html").read_text())
    assert "2 nmac_uav_aircraft" in verdict and "violates keep_apart" in verdict
    assert "2 of 2 runs" in verdict
