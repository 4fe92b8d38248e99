"""A sweep's dozens of variants in one chart: the legend goes below, the axes keep their size."""

from __future__ import annotations

import re
import warnings

import numpy as np

from corridor.analysis.plots import line_chart


def test_many_series_keep_the_axes_and_every_label() -> None:
    t = np.linspace(0.0, 10.0, 50)
    series = [(f"p100_r1200_L{i}", t, np.sin(t + i)) for i in range(45)]  # the merging sweep has 45 variants
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # matplotlib: "constrained_layout not applied because axes sizes collapsed"
        out = line_chart(series, "delay", "t [s]", "delay [s]")
    assert len(re.findall(r'id="series:p100_r1200_L\d+"', out)) == 45
    assert all(f">p100_r1200_L{i}<" in out for i in range(45))  # legend text stays text
    few = line_chart(series[:3], "delay", "t [s]", "delay [s]")
    height = [float(re.search(r'<svg[^>]*height="([\d.]+)pt"', s).group(1)) for s in (few, out)]  # type: ignore[union-attr]
    assert height[1] > height[0]  # the figure grew for the rows of the legend below it
