"""`compd report`: the page holds what an engineer judges a calibration by,
marks the calibration and held-out windows, says "not recorded" for what the
provenance lacks, escapes every text from a file (a hostile model name,
provenance string, column or file name injects no markup), follows the
output-file rules, and, opened in headless chromium, draws every figure with
no text over another and fetches nothing."""

from __future__ import annotations

import hashlib
import json
import re
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from tests.compd.faces.webdriver import browser_missing, headless_chromium

HOSTILE = "<script>alert(1)</script><img src=x onerror=alert(2)>"


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two simulated records at 60 s and the bundled plant model, its
    provenance saying it was fitted on the first (and holding hostile text)."""
    from compd.infiles import load_model
    from models.modelfile import save_model

    d = tmp_path_factory.mktemp("report")
    heat, etve = d / "heat.csv", d / "etve.csv"
    assert main(["sim", "--record", str(heat), "--program", "constant", "--period-s", "60",
                 "--seed", "2", "--hours", "6"]) == 0
    assert main(["sim", "--record", str(etve), "--program", "etve", "--period-s", "60",
                 "--seed", "1", "--hours", "12"]) == 0
    model = load_model("sim_machine")
    model.provenance = {
        "tool": "compd fit", "compd_version": "0.0.test",
        "command_line": f"compd fit heat.csv --column dz_um --term '{HOSTILE}'",
        "data_file": "heat.csv",
        "data_sha256": hashlib.sha256(heat.read_bytes()).hexdigest(),
        "structure": "ridge (λ = 0.001)", "validation_fit_percent": 93.2,
        "runners_up": ["ridge: validation 93.21 %", f"{HOSTILE}: validation 1.00 %"],
    }
    model.name = f"plant {HOSTILE}"
    save_model(model, d / "plant.toml")
    return {"dir": d, "model": d / "plant.toml", "heat": heat, "etve": etve}


def _report(runs: dict[str, Path], name: str, *extra: str) -> str:
    out = runs["dir"] / name
    assert main(["report", str(runs["model"]), str(runs["heat"]), str(runs["etve"]),
                 "-o", str(out), "--force", *extra]) == 0
    return out.read_text(encoding="utf-8")


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: set[str] = set()
        self.attrs: set[str] = set()
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.add(tag)
        self.attrs.update(k for k, _ in attrs)

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def test_the_page_holds_the_calibration_and_escapes_what_files_say(
        runs: dict[str, Path]) -> None:
    page = _report(runs, "r.html")
    parsed = _Tags()
    parsed.feed(page)
    assert not {"script", "img", "iframe", "object", "link", "a"} & parsed.tags
    assert not [a for a in parsed.attrs if a.startswith("on")]
    assert not re.search(r'\b(src|href)="(?!#)', page)  # nothing fetched
    text = "".join(parsed.text)
    assert text.count(HOSTILE) >= 4  # the name, the command line, a runner-up, in SVG too
    for heading in ("Figures per record and window", "Each term's step response",
                    "Poles and time constants", "Validation: how the structure was chosen",
                    "ISO 230-3: drift over the run and environmental variation error",
                    "Provenance"):
        assert heading in text
    assert "heat.csv (calibration)" in text and "etve.csv (held out)" in text
    assert "Stability of the choice: not recorded" in text
    assert "chosen" in text and "93.21 %" in text
    assert "not an ETVE run: the spindle turns" in text  # heat.csv
    assert re.search(r"ETV \d+\.\d\d K", text)  # etve.csv: the room's variation drawn
    assert hashlib.sha256(runs["etve"].read_bytes()).hexdigest() in text
    assert page.count("<svg") == 4  # two records, the step responses, the drift


def test_a_stability_figure_is_shown_when_recorded_and_a_record_split(
        runs: dict[str, Path], tmp_path: Path) -> None:
    from compd.infiles import load_model
    from models.modelfile import save_model

    model = load_model(runs["model"])
    model.provenance = {**model.provenance, "selection_stability": "ridge in 9 of 10 resamples"}
    path = tmp_path / "stable.toml"
    save_model(model, path)
    out = tmp_path / "s.html"
    assert main(["report", str(path), str(runs["etve"]), "-o", str(out),
                 "--held-out-from", "21600"]) == 0
    text = out.read_text(encoding="utf-8")
    assert "ridge in 9 of 10 resamples" in text and "not recorded" not in text.split(
        "How stable the choice was")[1].split("ISO 230-3")[0]
    rows = re.findall(r"<tr><td class=\"name\">etve.csv</td><td>([a-z ]+)</td><td>([^<]+)</td>",
                      text)
    assert rows == [("calibration", "0 … 6 h"), ("held out", "6 … 12 h")]


def test_the_output_file_rules(runs: dict[str, Path], capsys: pytest.CaptureFixture[str]
                               ) -> None:
    out = runs["dir"] / "exists.html"
    out.write_text("old", encoding="utf-8")
    argv = ["report", str(runs["model"]), str(runs["heat"]), "-o"]
    assert main([*argv, str(out)]) == 73
    assert "exists; give --force" in capsys.readouterr().err and out.read_text() == "old"
    assert main([*argv, str(runs["heat"]), "--force"]) == 73  # never over an input
    assert "is the input" in capsys.readouterr().err
    assert main([*argv, str(runs["dir"] / "r.png")]) == 64
    assert "name it .html" in capsys.readouterr().err
    assert main(["report", str(runs["model"]), str(runs["heat"]), "-o",
                 str(runs["dir"] / "c.html"), "--column", "nope"]) == 65
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'nope'" in err


# In the page: every text box (HTML text, per line, and each SVG <text>) and
# whether any two overlap; every <svg>'s size and how many drawn shapes it has.
_LAYOUT = """
const boxes = [];
const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
for (let n = walker.nextNode(); n; n = walker.nextNode()) {
  if (!n.textContent.trim() || n.parentElement.closest("svg")) continue;
  const r = document.createRange(); r.selectNodeContents(n);
  for (const b of r.getClientRects()) if (b.width > 0)
    boxes.push({t: n.textContent.trim().slice(0, 40), g: "html", x0: b.left, y0: b.top,
                x1: b.right, y1: b.bottom});
}
document.querySelectorAll("svg").forEach((svg, i) => svg.querySelectorAll("text").forEach(e => {
  const b = e.getBoundingClientRect();
  if (b.width > 0) boxes.push({t: e.textContent.slice(0, 40), g: "svg" + i, x0: b.left,
                               y0: b.top, x1: b.right, y1: b.bottom}); }));
const overlaps = [];
for (let i = 0; i < boxes.length; i++) for (let j = i + 1; j < boxes.length; j++) {
  const a = boxes[i], b = boxes[j];
  const w = Math.min(a.x1, b.x1) - Math.max(a.x0, b.x0);
  const h = Math.min(a.y1, b.y1) - Math.max(a.y0, b.y0);
  if (w > 1 && h > 1) overlaps.push([a.t, b.t, a.g, b.g]); }
const svgs = [...document.querySelectorAll("svg")].map(s => {
  const b = s.getBoundingClientRect();
  const drawn = [...s.querySelectorAll("path, polyline, rect, use")].filter(e => {
    const r = e.getBoundingClientRect(); return r.width > 0 || r.height > 0; }).length;
  return {w: b.width, h: b.height, drawn: drawn, texts: s.querySelectorAll("text").length}; });
return JSON.stringify({boxes: boxes.length, overlaps: overlaps, svgs: svgs,
                       fetched: performance.getEntriesByType("resource").length,
                       width: document.documentElement.scrollWidth,
                       view: window.innerWidth});
"""


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_chromium_draws_every_figure_with_no_text_over_another(runs: dict[str, Path]) -> None:
    _report(runs, "seen.html")
    with headless_chromium(width=1280, height=1400) as browser:
        browser.get((runs["dir"] / "seen.html").as_uri())
        got: dict[str, Any] = json.loads(browser.script(_LAYOUT))
    assert got["boxes"] > 100
    assert got["overlaps"] == [], got["overlaps"][:10]
    assert len(got["svgs"]) == 4
    for svg in got["svgs"]:
        assert svg["w"] > 600 and svg["h"] > 150, svg
        assert svg["drawn"] > 20 and svg["texts"] > 10, svg
    assert got["fetched"] == 0
    assert got["width"] <= got["view"]  # nothing wider than the window
