"""Every report chart, rendered by a real browser (Debian's chromium via playwright), has labelled
axes with readable tick labels. Skipped without chromium or playwright, except under CI."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from service.cli.main import main

#: Per axes of every matplotlib SVG: its axis groups, each with its tick label texts, the label
#: text (what is not a tick), and the rendered tick label height in CSS pixels.
AXES_JS = """
() => [...document.querySelectorAll('svg')].map((svg, k) => {
  const box = svg.getBoundingClientRect();
  const axes = [...svg.querySelectorAll('g[id^="axes_"]')].map((ax) =>
    [...ax.querySelectorAll(':scope > g[id^="matplotlib.axis"]')].map((axis) => {
      const ticks = [...axis.querySelectorAll('g[id^="xtick"] text, g[id^="ytick"] text')];
      const label = [...axis.querySelectorAll('text')].filter((t) => !ticks.includes(t));
      return {
        ticks: ticks.map((t) => t.textContent.trim()).filter((t) => t),
        label: label.map((t) => t.textContent.trim()).join(' '),
        height: Math.min(...ticks.map((t) => t.getBoundingClientRect().height), 99),
      };
    }));
  return {index: k, width: box.width, axes};
})
"""


@pytest.fixture(scope="module")
def reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One report of each command, from simulated data."""
    d = tmp_path_factory.mktemp("browser-reports")
    out = {k: d / f"{k}.html" for k in ("calibrate", "diagnose", "positions", "navigate")}
    pos, cap, rec, truth = d / "pos.csv", d / "cap.bin", d / "rec.csv", d / "truth.json"
    assert main(["simulate", "--seed", "2", "-o", str(pos)]) == 0
    assert main(["calibrate", str(pos), "--latitude", "45", "--report", str(out["calibrate"])]) == 0
    assert main(["diagnose", str(pos), "--latitude", "45", "--report", str(out["diagnose"])]) == 0
    assert main(["simulate", "--capture", str(cap), "--rate", "100", "--first-hold", "40"]) == 0
    assert main(["positions", str(cap), "--format", "kvh-a", "--rate", "100", "-o",
                 str(d / "cap.csv"), "--report", str(out["positions"])]) == 0  # fmt: skip
    assert main(["simulate", "--trajectory", "static", "--duration", "1800", "--rate", "10",
                 "--recording", str(rec), "--truth-out", str(truth)]) == 0  # fmt: skip
    assert main(["navigate", str(rec), "--format", "csv", "--coefficients", str(truth),
                 "--latitude", "45", "--report", str(out["navigate"])]) == 0  # fmt: skip
    return out


@pytest.mark.parametrize("command", ["calibrate", "diagnose", "positions", "navigate"])
def test_every_chart_has_labelled_axes_with_readable_ticks(
    browser: Any, reports: dict[str, Path], command: str, tmp_path: Path
) -> None:
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(reports[command].as_uri())
    page.screenshot(path=str(tmp_path / f"{command}.png"), full_page=True)
    charts = page.evaluate(AXES_JS)
    page.close()
    assert not errors, errors
    assert charts, f"{command}: no chart"
    for chart in charts:
        where = f"{command} chart {chart['index']}"
        assert chart["width"] >= 300, f"{where} is drawn {chart['width']:.0f} px wide"
        assert chart["axes"], f"{where} has no axes"
        for axes in chart["axes"]:
            shown = [a for a in axes if a["ticks"]]
            assert shown, f"{where}: axes without tick labels"
            assert any(a["label"] for a in shown), f"{where}: no axis label"
            for axis in shown:
                assert len(axis["ticks"]) >= 2, f"{where}: ticks {axis['ticks']}"
                assert axis["height"] >= 8, f"{where}: tick labels {axis['height']:.1f} px high"
