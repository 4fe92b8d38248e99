"""The reports of short real batches (merging, UAV encounter, parking lot), opened in a real browser
(Debian's Chromium driven by playwright): they load without console errors, every figure has a
non-empty drawing, and no "nan" or "– ± –" stands where a value is expected."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO, SCENARIOS

CHROMIUM = Path("/usr/bin/chromium")
BATCHES = {  # scenario -> (options, the figure kinds its report must show)
    "merging": (["--runs", "2", "--set", "duration=60", "--set", "warmup=10", "--variant", "sumo_default",
                 "--variant", "v2x_fifo"], {"bands", "timespace", "distribution", "bars"}),
    "uav_encounter": (["--runs", "2", "--set", "duration=40"], {"bands", "tracks", "altitude", "distribution"}),
    "parking_lot": (["--runs", "2", "--set", "duration=15"], {"lot", "histogram", "distribution"}),
}


@pytest.fixture(scope="module")
def browser():  # noqa: ANN201 - a playwright Browser
    if not CHROMIUM.is_file():
        pytest.fail("no /usr/bin/chromium: apt-get install -y chromium (make test installs it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        yield b
        b.close()


def _batch(name: str, out: Path) -> Path:
    opts, _ = BATCHES[name]
    res = subprocess.run([sys.executable, "-m", "corridor.cli", str(SCENARIOS / f"{name}.yaml"),
                          "--out", str(out), "--quiet", *opts], capture_output=True, text=True, cwd=REPO, timeout=900)
    assert res.returncode in (0, 1), res.stderr[-2000:]  # 1: a safety event (the UAV none variant)
    return out / "report.html"


FIGURES_JS = """() => [...document.querySelectorAll('figure.plot')].map(f => {
  const s = f.querySelector('svg'); const r = s ? s.getBoundingClientRect() : {width: 0, height: 0};
  return {cls: f.className, w: r.width, h: r.height,
          marks: s ? s.querySelectorAll('path, image, use').length : 0};
})"""


@pytest.mark.parametrize("name", list(BATCHES))
def test_report_in_a_browser(name: str, browser, tmp_path: Path) -> None:  # noqa: ANN001
    report = _batch(name, tmp_path / name)
    page = browser.new_page(viewport={"width": 1200, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(report.as_uri())
    page.wait_for_load_state("load")
    assert errors == []
    figs = page.evaluate(FIGURES_JS)
    kinds = {f["cls"].split()[-1] for f in figs}
    assert BATCHES[name][1] <= kinds, kinds
    assert all(f["w"] > 100 and f["h"] > 50 and f["marks"] > 5 for f in figs), figs
    assert "Metric glossary" in page.inner_text("#glossary")
    page.evaluate("() => document.getElementById('glossary').remove()")  # it says where NaN means none
    text = page.inner_text("body")
    assert not re.search(r"\bnan\b", text, re.I), re.search(r".{40}\bnan\b.{40}", text, re.I | re.S)
    assert "– ± –" not in text and "[—, —]" not in text
    assert "Verdict" in text
    page.close()
