"""The HTML report (eponet.core.html_report): its content against run.json, ``eponet report`` and
``output.save: [report]``, and the page in a real headless Chromium (skipped where there is none)."""

import base64
import html
import io
import json
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from eponet.core.html_report import PANEL_FRAMES, REPORT_FILE, render_report, scores_chart_svg, write_report
from eponet.core.outputs import PANEL_HEIGHT, TITLE_HEIGHT
from eponet.core.pipeline import Pipeline
from eponet.core.report_panels import pick_frames
from eponet.core.spec import parse_spec
from tests.chromium import Chromium, chromium_binary
from tests.conftest import REPO

FRAMES = 8  # of the demo clip, at half size: a few seconds on a CPU, and J, F and T all defined


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> Path:
    """A scored run of the demo clip that saved everything the report shows, and the report itself."""
    out = tmp_path_factory.mktemp("report") / "run"
    spec = parse_spec({"preset": "epo", "input": {"path": str(REPO / "examples" / "demo"), "resolution": "240p",
                                                   "scale": 0.5, "max_frames": FRAMES},
                       "stages": {"refiner": {"plugin": "threshold"}},
                       "output": {"dir": str(out), "save": ["masks", "saliency", "ed", "overlay", "panels", "report"]},
                       "run": {"workers": 1}, "evaluate": {"dataset": "davis2016"}, "cache": {"enabled": False}})
    Pipeline(spec).run()
    return out


@pytest.fixture
def run_copy(demo_run, tmp_path) -> Path:
    """A copy of the demo run to alter."""
    return Path(shutil.copytree(demo_run, tmp_path / "run"))


def _manifest(folder: Path) -> dict:
    return json.loads((folder / "run.json").read_text())


def _section(page: str, name: str) -> str:
    """The text of ``<section id=name>`` (or the summary ``<header>``)."""
    match = re.search(rf'<(section|header) id="{name}".*?</\1>', page, re.S)
    assert match, name
    return match.group(0)


def _row(table_html: str, sequence: str) -> list[str]:
    row = re.search(rf'<tr data-sequence="{re.escape(sequence)}">(.*?)</tr>', table_html, re.S).group(1)
    return [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row, re.S)]


# -- content -----------------------------------------------------------------------------------------------------
def test_output_save_report_writes_index_html_with_every_section(demo_run):
    page = (demo_run / REPORT_FILE).read_text()
    order = [page.index(marker) for marker in ('id="summary"', 'id="evaluation"', 'id="timings"', 'id="sequences"',
                                               'id="manifest"')]
    assert order == sorted(order)
    assert page.rindex("<section") == page.index('<section id="manifest"')  # the record comes last
    # nothing from the network, no script
    assert "<script" not in page
    assert not re.findall(r'(?:src|href)="(?!data:|demo/)[^"]*"', page)


def test_the_manifest_at_the_bottom_is_run_json(demo_run):
    section = _section((demo_run / REPORT_FILE).read_text(), "manifest")
    text = re.search(r"<pre>(.*)</pre>", section, re.S).group(1)
    assert json.loads(html.unescape(text)) == _manifest(demo_run)


def test_timings_are_run_json_s(demo_run):
    entry = _manifest(demo_run)["sequences"]["demo"]
    cells = _row(_section((demo_run / REPORT_FILE).read_text(), "timings"), "demo")
    stages = list(entry["timings_s"])
    assert stages[:2] == ["flow", "trajectories"] and "write" in stages
    assert cells[0] == "demo" and cells[1] == str(FRAMES)
    assert cells[2:2 + len(stages)] == [f"{entry['timings_s'][s]:.2f}" for s in stages]
    assert cells[2 + len(stages)] == f"{entry['seconds']:.2f}"
    assert cells[3 + len(stages)] == f"{entry['seconds'] / FRAMES:.3f}"


def test_scores_chart_and_attributes_are_the_evaluation_s(demo_run):
    evaluation = _manifest(demo_run)["evaluation"]
    scores = evaluation["sequences"]["demo"]
    section = _section((demo_run / REPORT_FILE).read_text(), "evaluation")
    cells = _row(section, "demo")
    expected = [f"{scores[m][s]:.3f}" for m in ("J", "F") for s in ("mean", "recall", "decay")]
    assert cells[1:8] == expected + [f"{scores['T']['mean']:.3f}"]
    assert cells[8] == f"{scores['frames_scored']} / {scores['frames_in_ground_truth']}"
    assert 0.3 < scores["J"]["mean"] < 1  # the demo object is found: the numbers checked are not all zero
    assert f"input.max_frames {FRAMES}" in section
    # the chart: one bar per measure for the sequence and for the mean, heights in proportion
    svg = re.search(r"<svg.*?</svg>", section, re.S).group(0)
    bars = {(b.get("data-sequence"), b.get("data-metric")): float(b.get("height"))
            for b in ElementTree.fromstring(svg).iter("{http://www.w3.org/2000/svg}rect") if b.get("class") == "bar"}
    assert set(bars) == {(s, m) for s in ("demo", "mean") for m in "JFT"}
    assert bars["demo", "J"] / bars["demo", "F"] == pytest.approx(scores["J"]["mean"] / scores["F"]["mean"], rel=0.01)
    # attributes: the demo's db_info.yml gives it OCC of DB, FM, OCC, OV
    attributes = re.search(r'<table class="attributes">.*?</table>', section, re.S).group(0)
    head = re.findall(r"<th(?: [^>]*)?>(.*?)</th>", attributes)
    assert head == ["sequence", "DB", "FM", "OCC", "OV", "J mean"]
    assert [c == "\u2713" for c in re.findall(r"<td[^>]*>(.*?)</td>", html.unescape(attributes))][1:5] == \
        [False, False, True, False]
    table = re.search(r'<table class="attribute-scores">.*?</table>', section, re.S).group(0)
    assert f"<td>OCC</td><td class=\"num\">{scores['J']['mean']:.3f}</td>" in table


def test_each_sequence_has_its_video_and_a_strip_of_panels(demo_run):
    section = _section((demo_run / REPORT_FILE).read_text(), "sequences")
    video = re.findall(r'<video [^>]*src="([^"]+)"', section)
    assert video == ["demo/overlay.mp4"] and (demo_run / video[0]).is_file()
    images = re.findall(r'<img src="([^"]+)"', section)
    stems = sorted(p.stem for p in (demo_run / "demo" / "panels").glob("*.png"))
    assert images == [f"demo/panels/{s}.png" for s in pick_frames(stems, PANEL_FRAMES)]
    assert len(images) == PANEL_FRAMES and all((demo_run / i).is_file() for i in images)
    assert f"frame {stems[-1]}" in section and f"{FRAMES} frames; input 427x240 px; processed at 214x120 px" in section


def test_without_overlay_and_panels_the_report_says_so_and_draws_panels_from_masks(run_copy):
    (run_copy / "demo" / "overlay.mp4").unlink()
    shutil.rmtree(run_copy / "demo" / "panels")
    section = _section(render_report(run_copy), "sequences")
    assert "<video" not in section and "No overlay video: add <code>overlay</code> to output.save" in section
    assert "Panels were not saved" in section and "over the input frames" in section
    images = re.findall(r'<img src="data:image/jpeg;base64,([^"]+)"', section)
    assert len(images) == PANEL_FRAMES
    strip = np.asarray(Image.open(io.BytesIO(base64.b64decode(images[0]))))
    # frame, ED, saliency and mask tiles of the 427x240 input, each under its title strip
    assert strip.shape == (TITLE_HEIGHT + PANEL_HEIGHT, 4 * 427, 3)
    frame = cv2.cvtColor(cv2.imread(str(REPO / "examples/demo/JPEGImages/240p/demo/00000.jpg")), cv2.COLOR_BGR2RGB)
    assert np.abs(strip[TITLE_HEIGHT:, :427].astype(int) - frame).mean() < 6  # the first tile is the frame


def test_panels_without_the_input_frames_or_without_any_maps(run_copy):
    manifest = _manifest(run_copy)
    manifest["spec"]["input"]["path"] = str(run_copy / "moved-away")
    shutil.rmtree(run_copy / "demo" / "panels")
    section = _section(render_report(run_copy, manifest), "sequences")
    assert "the input frames could not be read from input.path" in section
    image = re.search(r'<img src="data:image/jpeg;base64,([^"]+)"', section).group(1)
    assert np.asarray(Image.open(io.BytesIO(base64.b64decode(image)))).shape[1] == 3 * 427
    for folder in ("masks", "saliency", "ed"):
        shutil.rmtree(run_copy / "demo" / folder)
    section = _section(render_report(run_copy, manifest), "sequences")
    assert "No panels: the run saved neither panels nor masks, saliency or ED" in section and "<img" not in section


def test_a_run_without_evaluation_or_with_a_failed_one(run_copy):
    manifest = _manifest(run_copy)
    del manifest["evaluation"]
    assert "Not evaluated: the spec has no <code>evaluate:</code> section" in render_report(run_copy, manifest)
    manifest["evaluation"] = {"error": "InputError: Annotations/240p <missing>"}
    assert "Scoring failed: InputError: Annotations/240p &lt;missing&gt;" in render_report(run_copy, manifest)


def test_a_sequence_cut_short_says_so(run_copy):
    manifest = _manifest(run_copy)
    manifest["sequences"]["demo"]["stopped"] = "demo/00020.jpg: cannot read image; its first 20 frames were kept"
    section = _section(render_report(run_copy, manifest), "sequences")
    assert '<p class="note">Cut short: demo/00020.jpg: cannot read image; its first 20 frames were kept.</p>' in section


def test_names_and_values_are_escaped(run_copy):
    manifest = _manifest(run_copy)
    manifest["sequences"] = {"<b>x</b>": {**manifest["sequences"]["demo"], "cached": ["<i>"]}}
    page = render_report(run_copy, manifest)
    assert "<b>" not in page and "<i>" not in page and "&lt;b&gt;x&lt;/b&gt;" in page
    assert "The sequence folder &lt;b&gt;x&lt;/b&gt;/ is missing" in page


def test_scores_chart_scales_bars_and_marks_missing_values():
    svg = scores_chart_svg([("a", {"J": 0.5, "F": 1.0, "T": None}), ("b", {"J": 0.25, "F": None, "T": 2.0})],
                           plot_height=100)
    bars = {(b.get("data-sequence"), b.get("data-metric")): float(b.get("height"))
            for b in ElementTree.fromstring(svg).iter("{http://www.w3.org/2000/svg}rect") if b.get("class") == "bar"}
    # a T of 2 stretches the axis to 2: the plot's 100 px are 2 units
    assert bars == {("a", "J"): 25.0, ("a", "F"): 50.0, ("b", "J"): 12.5, ("b", "T"): 100.0}
    assert svg.count(">n/a<") == 2


def test_pick_frames():
    stems = [f"{t:05d}" for t in range(10)]
    assert pick_frames(stems, 3) == ["00000", "00004", "00009"]
    assert pick_frames(stems[:2], 3) == stems[:2] and pick_frames(stems, 1) == ["00000"]


def test_a_failed_scoring_is_in_the_report(tmp_path, monkeypatch):
    from eponet.core.registry import Registry

    def fail(self, spec, sequences):
        raise RuntimeError("scorer <down>")

    monkeypatch.setattr(Registry, "evaluate", fail)
    out = tmp_path / "run"
    spec = parse_spec({"preset": "epo", "input": {"path": str(REPO / "examples" / "demo"), "resolution": "240p",
                                                   "scale": 0.25, "max_frames": 4},
                       "stages": {"refiner": {"plugin": "threshold"}}, "output": {"dir": str(out), "save": ["report"]},
                       "run": {"workers": 1}, "evaluate": {"dataset": "davis2016"}, "cache": {"enabled": False}})
    with pytest.raises(RuntimeError):
        Pipeline(spec).run()
    page = (out / REPORT_FILE).read_text()
    assert "Scoring failed: RuntimeError: scorer &lt;down&gt;" in page
    assert "No panels: the run saved neither panels nor masks" in page


# -- eponet report -----------------------------------------------------------------------------------------------
def _report(*args):
    return subprocess.run([sys.executable, "-m", "eponet", "report", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_eponet_report_rewrites_the_page(run_copy):
    (run_copy / REPORT_FILE).unlink()
    result = _report(run_copy)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"wrote {run_copy / REPORT_FILE}"
    assert (run_copy / REPORT_FILE).read_text() == render_report(run_copy)


@pytest.mark.parametrize("case", ["missing", "no-record", "bad-json", "not-a-record"])
def test_eponet_report_on_a_folder_that_is_not_a_run_is_one_line_and_exit_2(tmp_path, case):
    folder = tmp_path / "folder"
    if case != "missing":
        folder.mkdir()
    if case == "bad-json":
        (folder / "run.json").write_text("{not json")
    if case == "not-a-record":
        (folder / "run.json").write_text("[1, 2]")
    result = _report(folder)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    expected = {"missing": f"error: {folder}: no such folder",
                "no-record": f"error: {folder}: not an eponet run (no run.json",
                "bad-json": f"error: {folder / 'run.json'}: not a readable run record (JSONDecodeError",
                "not-a-record": f"error: {folder / 'run.json'}: not an eponet run record"}[case]
    assert lines[0].startswith(expected) and not (folder / REPORT_FILE).exists()


# -- in a browser ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def browser():
    binary = chromium_binary()
    if binary is None:
        pytest.skip("no Chromium: none on PATH and no $EPONET_CHROMIUM (Debian: apt-get install chromium; .ci/run installs it)")
    with Chromium(binary) as chromium:
        yield chromium


def _not_blank(png: bytes) -> float:
    return float(np.asarray(Image.open(io.BytesIO(png)).convert("L"), np.float32).std())


def test_the_report_plays_in_chromium(demo_run, browser):
    page = browser.load(demo_run / REPORT_FILE)
    assert page.errors == []
    assert len(page.media) == 1 and page.media[0]["error"] is None
    duration = page.media[0]["duration"]
    # the overlay's 8 frames at 24 fps (the demo is a folder of frames)
    assert isinstance(duration, float) and duration == pytest.approx(FRAMES / 24, abs=0.05)
    assert (page.media[0]["width"], page.media[0]["height"]) == (428, 240)
    assert len(page.images) == PANEL_FRAMES and all(i["natural_width"] == 2137 for i in page.images)
    assert _not_blank(page.screenshot) > 20


def test_drawn_panels_show_in_chromium(run_copy, browser):
    shutil.rmtree(run_copy / "demo" / "panels")
    page = browser.load(write_report(run_copy))
    assert page.errors == [] and len(page.images) == PANEL_FRAMES
    assert all(i["natural_width"] == 4 * 427 for i in page.images)


def test_the_browser_check_sees_a_missing_panel_and_a_video_browsers_cannot_play(run_copy, browser):
    """The checks above can fail: a panel file gone is a console error, an MPEG-4 Part 2 video has no duration."""
    panel = sorted((run_copy / "demo" / "panels").glob("*.png"))[0]
    write_report(run_copy)
    panel.unlink()
    writer = cv2.VideoWriter(str(run_copy / "demo" / "overlay.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 24, (428, 240))
    for t in range(FRAMES):
        writer.write(np.full((240, 428, 3), 30 * t, np.uint8))
    writer.release()
    page = browser.load(run_copy / REPORT_FILE)
    assert any("ERR_FILE_NOT_FOUND" in e and panel.name in e for e in page.errors), page.errors
    assert page.media[0]["error"] is not None and not isinstance(page.media[0]["duration"], float)
    assert [i["natural_width"] for i in page.images].count(0) == 1
