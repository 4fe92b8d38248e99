"""The metric glossary comes from the components' declarations (``Component.metrics``): every column
a real run writes is declared, and docs/reference/metrics.md is what the generator writes."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from corridor.analysis.glossary import declared_metrics, glossary_markdown, glossary_section, match
from corridor.analysis.report import NON_METRICS
from corridor.scenario import load
from tests.conftest import REPO, SCENARIOS


def test_every_column_of_a_real_merging_run_is_declared(tmp_path: Path) -> None:
    from corridor import batch
    from corridor.run import execute

    path = SCENARIOS / "merging.yaml"
    sc, raw = load(path, ["duration=20", "warmup=0"])
    specs = batch.expand(sc, raw, str(path), 1, out_dir=str(tmp_path), variants=["sumo_default", "v2x_cps"])
    df = pd.DataFrame([execute(s) for s in specs])
    assert (df["status"] == "ok").all(), df["error"].tolist()
    cols = [c for c in df.columns if c not in NON_METRICS and not c.startswith("draw.")]
    known = match(cols, declared_metrics(sc))
    assert [c for c in cols if c not in known] == []
    assert known["min_ttc_s"][0] == "monitor.surrogate_safety" and known["min_ttc_s"][1].unit == "s"
    assert known["merge_loss_ramp_s"][1].name == "merge_loss_*_s"
    section = glossary_section(cols, sc)
    assert "<code>v2x_delivery_ratio</code>" in section and "controller.v2x_merging" in section
    assert "(not declared by its component)" not in section


def test_reference_page_is_generated() -> None:
    page = (REPO / "docs" / "reference" / "metrics.md").read_text()
    assert page == glossary_markdown(), "regenerate: python -m corridor.analysis.glossary docs/reference/metrics.md"
    assert "| `nmac` |" in page and "(safety event)" in page


def test_every_component_that_writes_columns_declares_them() -> None:
    from corridor.analysis.glossary import _all_components, _writes_columns

    undeclared = [label for label, cls in _all_components()
                  if _writes_columns(cls) and getattr(cls, "metrics", None) is None]
    assert undeclared == []
