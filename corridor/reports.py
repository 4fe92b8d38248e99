"""Batch reports, found through the ``corridor.reports`` entry-point group.

Each entry point is a callable ``write(df, scenario, out_dir, scenario_path) -> Path | None`` that
writes one report of a finished batch into its folder (corridor's own: ``html`` ->
``corridor.analysis.report:write_batch_report``, which writes ``report.html``).  Writers run in
the order of their names.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

GROUP = "corridor.reports"


def write_reports(df: Any, scenario: Any, out_dir: Path, scenario_path: Path | str | None) -> list[Path]:
    """Run every installed report writer on the batch's rows; returns the files written."""
    written = []
    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        path = ep.load()(df, scenario, Path(out_dir), scenario_path)
        if path is not None:
            written.append(Path(path))
    return written
