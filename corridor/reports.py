"""Batch reports and report sections, found through their entry-point groups.

Each ``corridor.reports`` entry point is a callable ``write(df, scenario, out_dir, scenario_path) ->
Path | None`` that writes one report of a finished batch into its folder (corridor's own: ``html`` ->
``corridor.analysis.report:write_batch_report``, which writes ``report.html``).  Writers run in
the order of their names.  Each ``corridor.report_sections`` entry point is a callable
``fn(out_dir, df, scenario, scenario_path) -> list[str]`` of HTML fragments that the HTML report
places after its distributions, in the order of their names.  Both groups are read by
:class:`corridor.entrypoints.Registry` (one name declared twice differently is an error).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from corridor.entrypoints import Registry

GROUP = "corridor.reports"
SECTIONS_GROUP = "corridor.report_sections"
REPORTS = Registry("report writer", GROUP)
REPORT_SECTIONS = Registry("report section", SECTIONS_GROUP)


def write_reports(df: Any, scenario: Any, out_dir: Path, scenario_path: Path | str | None) -> list[Path]:
    """Run every installed report writer on the batch's rows; returns the files written."""
    written = []
    for name in REPORTS.names():
        path = REPORTS.get(name)(df, scenario, Path(out_dir), scenario_path)
        if path is not None:
            written.append(Path(path))
    return written


def report_sections(out_dir: Path, df: Any, scenario: Any, scenario_path: Path | str | None) -> list[str]:
    """The HTML fragments of every installed report section, in the order of their names."""
    sections: list[str] = []
    for name in REPORT_SECTIONS.names():
        sections += REPORT_SECTIONS.get(name)(out_dir, df, scenario, scenario_path)
    return sections
