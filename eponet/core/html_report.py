"""The HTML report of a run, ``index.html`` in its output folder (``eponet report OUT_DIR``, ``output.save: [report]``).

The page is self-contained in the sense that matters for a results folder: nothing outside the run's folder is
referenced, nothing is fetched from the network, there is no script; styles and charts (SVG) are inline. Files the
run wrote (``<sequence>/overlay.mp4``, ``<sequence>/panels/*.png``) are *referenced* relative to ``index.html``
rather than embedded: a DAVIS run's overlays are tens of MB, which base64 would grow by a third into one page that
must load whole before anything shows, while a referenced video is streamed and seeked by the browser; the page
keeps working when the folder is moved, copied or served as a whole. Pictures the report draws itself (when
``panels`` were not saved) are embedded as JPEG data URIs, so the report only ever adds ``index.html``.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from urllib.parse import quote

import cv2
import numpy as np

from .errors import InputError
from .io import atomic_write_bytes, list_images
from .outputs import ED_PANEL_FLOOR_PX
from .report_panels import draw_panels, pick_frames

__all__ = ["REPORT_FILE", "PANEL_FRAMES", "read_run", "render_report", "write_report", "scores_chart_svg"]

#: The report's file name in the run's folder.
REPORT_FILE = "index.html"
#: Frames per sequence whose panels the report shows (the first, the last and evenly spaced ones between).
PANEL_FRAMES = 3

_METRIC_COLOURS = {"J": "#4e79a7", "F": "#f28e2b", "T": "#59a14f"}
_STAGE_COLOURS = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f")
_DASH = "\u2013"

_STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1240px; padding: 1em 1.5em; color: #222; }
h1 { font-size: 1.5em; } h2 { border-bottom: 1px solid #ccc; margin-top: 1.8em; } h3 { margin-bottom: .3em; }
table { border-collapse: collapse; margin: .6em 0; } th, td { padding: .2em .6em; border-bottom: 1px solid #e3e3e3; }
th { text-align: left; background: #f4f4f4; } td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.overall td { font-weight: 600; border-top: 2px solid #999; }
.note { color: #7a4b00; background: #fff6e0; padding: .4em .7em; border-left: 3px solid #e0a000; }
.facts { color: #444; } figure { margin: .5em 0; } figcaption { color: #555; font-size: .9em; }
.strip img, video { max-width: 100%; height: auto; display: block; background: #000; }
pre { background: #f7f7f7; padding: .8em; overflow-x: auto; font-size: 12px; }
svg text { font: 11px system-ui, sans-serif; fill: #333; }
"""


def read_run(out_dir: str | Path) -> dict:
    """The record (``run.json``) of the run in ``out_dir``; :class:`InputError` (one line) when ``out_dir`` is not
    an eponet run's folder."""
    out_dir = Path(out_dir)
    record = out_dir / "run.json"
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: no such folder")
    if not record.is_file():
        raise InputError(f"{out_dir}: not an eponet run (no run.json; eponet run writes one into output.dir)")
    try:
        manifest = json.loads(record.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{record}: not a readable run record ({exc.__class__.__name__}: {exc})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("sequences"), dict):
        raise InputError(f"{record}: not an eponet run record (it has no 'sequences')")
    return manifest


def write_report(out_dir: str | Path, manifest: dict | None = None, *, frames: int = PANEL_FRAMES) -> Path:
    """Write ``out_dir/index.html`` (atomically) for the run in ``out_dir`` (its ``run.json``, or ``manifest``
    when given); returns its path. See :func:`render_report`."""
    path = Path(out_dir) / REPORT_FILE
    atomic_write_bytes(path, render_report(out_dir, manifest, frames=frames).encode())
    return path


def render_report(out_dir: str | Path, manifest: dict | None = None, *, frames: int = PANEL_FRAMES) -> str:
    """The report page of the run in ``out_dir``: a summary, the evaluation (J / F / T per sequence with a chart,
    the attribute tables) when the run was scored, the stage timings, per sequence its overlay video and the
    panels of ``frames`` frames, and the record itself at the bottom.

    Where ``panels`` were not saved, the strip is drawn from the saved masks, saliency and ED over the input
    frames (when ``input.path`` can still be read) and says so; where ``overlay`` was not saved, the page says so.
    """
    out_dir = Path(out_dir)
    manifest = read_run(out_dir) if manifest is None else manifest
    sequences = manifest.get("sequences") or {}
    evaluation = manifest.get("evaluation") if isinstance(manifest.get("evaluation"), dict) else None
    title = f"eponet run: {out_dir.resolve().name}"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<link rel="icon" href="data:,">',  # no favicon request
        f"<title>{_e(title)}</title><style>{_STYLE}</style></head><body>",
        _summary_section(title, out_dir, manifest),
        _evaluation_section(evaluation),
        _timings_section(sequences),
        '<section id="sequences"><h2>Sequences</h2>',
        *(_sequence_section(k, name, entry, out_dir, manifest, frames)
          for k, (name, entry) in enumerate(sequences.items())),
        "</section>",
        '<section id="manifest"><h2>Run manifest (run.json)</h2>',
        f"<pre>{_e(json.dumps(manifest, indent=2, ensure_ascii=False))}</pre></section>",
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def scores_chart_svg(rows: list[tuple[str, dict]], *, plot_height: int = 180) -> str:
    """An inline SVG bar chart of J, F and T means, one group of bars per ``(label, {"J": v, "F": v, "T": v})``
    row (``None``: no bar, ``n/a`` under its place). The y axis runs from 0 to 1 (further if a T is above 1);
    every bar has a ``<title>`` with its value."""
    metrics = ("J", "F", "T")
    top = max([1.0] + [float(v[m]) for _, v in rows for m in metrics if _finite(v.get(m))])
    bar, gap, left, header, bottom = 13, 18, 38, 28, 72
    group = bar * len(metrics) + gap
    width = max(340, left + group * len(rows) + 10)
    height = header + plot_height + bottom
    y = lambda value: header + plot_height * (1 - value / top)  # noqa: E731
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" role="img" aria-label="J, F and T per sequence">']
    for tick in np.linspace(0, top, 5):
        out.append(f'<line x1="{left}" x2="{width - 6}" y1="{y(tick):.1f}" y2="{y(tick):.1f}" stroke="#ddd"/>'
                   f'<text x="{left - 4}" y="{y(tick) + 4:.1f}" text-anchor="end">{tick:.2f}</text>')
    for k, metric in enumerate(metrics):  # the legend
        out.append(f'<rect x="{left + 8 + 72 * k}" y="6" width="10" height="10" fill="{_METRIC_COLOURS[metric]}"/>'
                   f'<text x="{left + 22 + 72 * k}" y="15">{metric} mean{" (lower is better)" * (metric == "T")}</text>')
    for g, (label, values) in enumerate(rows):
        x0 = left + gap / 2 + g * group
        for k, metric in enumerate(metrics):
            value, x = values.get(metric), x0 + k * bar
            if _finite(value):
                out.append(f'<rect class="bar" data-metric="{metric}" data-sequence="{_e(label)}" x="{x:.1f}" '
                           f'y="{y(value):.1f}" width="{bar - 2}" height="{header + plot_height - y(value):.1f}" '
                           f'fill="{_METRIC_COLOURS[metric]}"><title>{_e(label)} {metric} {value:.3f}</title></rect>')
            else:
                out.append(f'<text x="{x + bar / 2:.1f}" y="{header + plot_height - 3}" text-anchor="middle" '
                           f'font-size="8">n/a</text>')
        cx, cy = x0 + bar * len(metrics) / 2, header + plot_height + 12
        out.append(f'<text x="{cx:.1f}" y="{cy}" text-anchor="end" transform="rotate(-40 {cx:.1f} {cy})">'
                   f'{_e(label)}</text>')
    out.append(f'<line x1="{left}" x2="{left}" y1="{header}" y2="{header + plot_height}" stroke="#888"/></svg>')
    return "".join(out)


# -- sections --------------------------------------------------------------------------------------------------
def _summary_section(title: str, out_dir: Path, manifest: dict) -> str:
    spec = manifest.get("spec") if isinstance(manifest.get("spec"), dict) else {}
    inputs = spec.get("input") if isinstance(spec.get("input"), dict) else {}
    plugins = manifest.get("plugins") if isinstance(manifest.get("plugins"), dict) else {}
    stages = ", ".join(f"{kind}={info.get('plugin')}" for kind, info in plugins.items() if isinstance(info, dict))
    invocation = manifest.get("invocation") if isinstance(manifest.get("invocation"), dict) else {}
    overrides = invocation.get("overrides")
    facts = [
        ("folder", str(out_dir.resolve())),
        ("started", manifest.get("started")),
        ("eponet", manifest.get("eponet")),
        ("spec file", manifest.get("spec_file")),
        ("preset", spec.get("preset")),
        ("stages", stages or None),
        ("input", inputs.get("path")),
        ("scale / max_frames", f"{inputs.get('scale')} / {inputs.get('max_frames')}" if inputs else None),
        ("seed", manifest.get("seed")),
        ("workers", manifest.get("workers")),
        ("sequences", len(manifest.get("sequences") or {})),
        ("total seconds", _num(manifest.get("total_seconds"), 1)),
        ("--set overrides", " ".join(overrides) if overrides else None),
        ("earlier runs into this folder", len(manifest.get("runs") or []) or None),
    ]
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in facts if v not in (None, ""))
    return f'<header id="summary"><h1>{_e(title)}</h1><table class="facts">{rows}</table></header>'


def _evaluation_section(evaluation: dict | None) -> str:
    head = '<section id="evaluation"><h2>Evaluation</h2>'
    if evaluation is None:
        return (head + '<p class="note">Not evaluated: the spec has no <code>evaluate:</code> section (add one, or '
                "score the masks with <code>eponet evaluate</code>).</p></section>")
    if "error" in evaluation:
        return head + f'<p class="note">Scoring failed: {_e(evaluation["error"])}</p></section>'
    per_sequence = {k: v for k, v in (evaluation.get("sequences") or {}).items() if isinstance(v, dict)}
    overall = evaluation.get("overall") or {}
    lines = [head, f'<p class="facts">{_e(evaluation.get("dataset"))} at {_e(evaluation.get("resolution"))}: '
                   f'{_e(evaluation.get("protocol"))}</p>']
    if evaluation.get("max_frames") is not None:
        scored = sum(e.get("frames_scored", 0) for e in per_sequence.values())
        total = sum(e.get("frames_in_ground_truth", 0) for e in per_sequence.values())
        lines.append(f'<p class="note">The run used input.max_frames {_e(evaluation["max_frames"])}: {scored} of '
                     f"{total} ground-truth frames scored.</p>")
    stats = [(m, s) for m in ("J", "F") for s in ("mean", "recall", "decay")] + [("T", "mean")]
    header = "".join(f'<th class="num">{m} {s}</th>' for m, s in stats)
    rows, missing = [], []
    for name, entry in per_sequence.items():
        cells = "".join(f'<td class="num" data-metric="{m}.{s}">{_num(_stat(entry, m, s))}</td>' for m, s in stats)
        scored = f"{entry.get('frames_scored', entry.get('n_frames', _DASH))} / {entry.get('frames_in_ground_truth', _DASH)}"
        rows.append(f'<tr data-sequence="{_e(name)}"><td>{_e(name)}</td>{cells}<td class="num">{_e(scored)}</td></tr>')
        if isinstance(entry.get("T"), dict) and entry["T"].get("missing"):
            missing.append(f"{_e(name)}: {_e(entry['T']['missing'])}")
    cells = "".join(f'<td class="num" data-metric="{m}.{s}">{_num(_stat(overall, m, s))}</td>' for m, s in stats)
    rows.append(f'<tr class="overall"><td>mean</td>{cells}<td class="num">{_e(overall.get("n_frames", ""))}</td></tr>')
    lines.append(f'<table class="scores"><thead><tr><th>sequence</th>{header}<th class="num">frames scored / in '
                 f'ground truth</th></tr></thead><tbody>{"".join(rows)}</tbody></table>')
    if missing:
        lines.append(f'<p class="facts">No T for {"; ".join(missing)}.</p>')
    chart_rows = [(name, {m: _stat(e, m, "mean") for m in ("J", "F", "T")}) for name, e in per_sequence.items()]
    chart_rows.append(("mean", {m: _stat(overall, m, "mean") for m in ("J", "F", "T")}))
    lines.append(f'<figure id="scores-chart">{scores_chart_svg(chart_rows)}<figcaption>J (region similarity) and F '
                 "(contour accuracy) means per sequence, higher is better; T (temporal instability), lower is "
                 "better.</figcaption></figure>")
    lines.append(_attribute_tables(per_sequence, evaluation.get("attributes") or {}))
    return "\n".join(lines) + "</section>"


def _attribute_tables(per_sequence: dict, table: dict) -> str:
    """Which sequence has which attribute (DAVIS ``db_info.yml``), and J with / without each attribute."""
    names = list(table) or sorted({a for e in per_sequence.values() for a in e.get("attributes") or []})
    if not names:
        return '<p class="facts">The data set gives no sequence attributes.</p>'
    head = "".join(f"<th>{_e(a)}</th>" for a in names)
    rows = "".join(f'<tr><td>{_e(s)}</td>{"".join(_mark(a in (e.get("attributes") or [])) for a in names)}'
                   f'<td class="num">{_num(_stat(e, "J", "mean"))}</td></tr>' for s, e in per_sequence.items())
    out = [f'<div id="attributes"><h3>Attributes</h3><table class="attributes"><thead><tr><th>sequence</th>{head}'
           f'<th class="num">J mean</th></tr></thead><tbody>{rows}</tbody></table>']
    if table:
        rows = "".join(f'<tr><td>{_e(a)}</td><td class="num">{_num(v.get("with"))}</td><td class="num">'
                       f'{_num(v.get("without"))}</td><td class="num">{_num(v.get("change"))}</td><td class="num">'
                       f'{_e(v.get("n_with"))} / {_e(v.get("n_without"))}</td></tr>'
                       for a, v in table.items() if isinstance(v, dict))
        out.append('<table class="attribute-scores"><thead><tr><th>attribute</th><th class="num">J with</th>'
                   '<th class="num">J without</th><th class="num">change</th><th class="num">sequences with / '
                   f"without</th></tr></thead><tbody>{rows}</tbody></table>")
    return "".join(out) + "</div>"


def _timings_section(sequences: dict) -> str:
    entries = {n: e for n, e in sequences.items() if isinstance(e, dict)}
    stages = list(dict.fromkeys(k for e in entries.values() for k in (e.get("timings_s") or {})))
    colours = {stage: _STAGE_COLOURS[k % len(_STAGE_COLOURS)] for k, stage in enumerate(stages)}
    head = "".join(f'<th class="num"><span style="color:{colours[s]}">&#9632;</span> {_e(s)}</th>' for s in stages)
    rows = []
    for name, entry in entries.items():
        timings = entry.get("timings_s") or {}
        frames = entry.get("frames") or 0
        per_frame = entry["seconds"] / frames if frames and _finite(entry.get("seconds")) else None
        cached = ", ".join(entry.get("cached") or []) + (" (resumed)" if entry.get("resumed") else "")
        rows.append(f'<tr data-sequence="{_e(name)}"><td>{_e(name)}</td><td class="num">{_e(frames)}</td>'
                    + "".join(f'<td class="num" data-stage="{_e(s)}">{_num(timings.get(s), 2)}</td>' for s in stages)
                    + f'<td class="num">{_num(entry.get("seconds"), 2)}</td><td class="num">{_num(per_frame, 3)}</td>'
                    f"<td>{_stage_bar(timings, colours)}</td><td>{_e(cached)}</td></tr>")
    return ('<section id="timings"><h2>Timings</h2><p class="facts">Seconds per stage (wall clock, as run.json '
            "records them; a cached stage only read its results).</p><table class=\"timings\"><thead><tr><th>sequence"
            f'</th><th class="num">frames</th>{head}<th class="num">total s</th><th class="num">s / frame</th>'
            f"<th>share</th><th>cached</th></tr></thead><tbody>{''.join(rows)}</tbody></table></section>")


def _stage_bar(timings: dict, colours: dict, width: int = 160) -> str:
    total = sum(v for v in timings.values() if _finite(v) and v > 0)
    if not total:
        return ""
    out, x = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="12">'], 0.0
    for stage, seconds in timings.items():
        if _finite(seconds) and seconds > 0:
            w = width * seconds / total
            out.append(f'<rect x="{x:.1f}" width="{w:.1f}" height="12" fill="{colours[stage]}">'
                       f"<title>{_e(stage)} {seconds:.2f} s</title></rect>")
            x += w
    return "".join(out) + "</svg>"


def _sequence_section(k: int, name: str, entry: dict, out_dir: Path, manifest: dict, frames: int) -> str:
    folder = out_dir / name
    entry = entry if isinstance(entry, dict) else {}
    parts = [f'<section class="sequence" id="seq-{k}" data-sequence="{_e(name)}"><h3>{_e(name)}</h3>',
             f'<p class="facts">{_e(_sequence_facts(entry))}</p>']
    for key, what in (("still_frames", "nothing moves (flow below 0.25 px)"),
                      ("covered_frames", "the mask covers more than 90% of the frame")):
        if entry.get(key):
            parts.append(f'<p class="note">Frames where {what}: {_e(", ".join(map(str, entry[key])))}.</p>')
    if entry.get("stopped"):  # cut short by a corrupt frame
        parts.append(f'<p class="note">Cut short: {_e(entry["stopped"])}.</p>')
    if not folder.is_dir():
        parts.append(f'<p class="note">The sequence folder {_e(name)}/ is missing.</p></section>')
        return "".join(parts)
    if (folder / "overlay.mp4").is_file():
        height, width = (entry.get("input_size") or [0, 0])[:2]
        size = f' width="{width + width % 2}" height="{height + height % 2}"' if width and height else ""
        parts.append(f'<video controls muted loop playsinline preload="metadata"{size} '
                     f'src="{_url(name, "overlay.mp4")}"></video>')
    else:
        parts.append('<p class="note">No overlay video: add <code>overlay</code> to output.save.</p>')
    panels = list_images(folder / "panels") if (folder / "panels").is_dir() else []
    if panels:
        figures = [_figure(_url(name, "panels", p.name), p.stem, _png_size(p))
                   for p in pick_frames(panels, frames)]
    else:
        figures = _drawn_panels(folder, name, manifest, frames, parts)
    if figures:
        parts.append(f'<div class="strip">{"".join(figures)}</div>')
    return "".join(parts) + "</section>"


def _sequence_facts(entry: dict) -> str:
    facts = [f"{entry.get('frames', '?')} frames"]
    if entry.get("input_size"):
        facts.append("input {1}x{0} px".format(*entry["input_size"]))
    if entry.get("processing_size"):
        facts.append("processed at {1}x{0} px".format(*entry["processing_size"]))
    if _finite(entry.get("seconds")):
        facts.append(f"{entry['seconds']:.2f} s")
    triplets = entry.get("triplets") or {}
    if triplets.get("count"):
        models = ", ".join(f"{m} {n}" for m, n in (triplets.get("models") or {}).items())
        facts.append(f"{triplets['count']} triplets ({models}; {triplets.get('fallbacks', 0)} fallbacks)")
    if _finite(entry.get("mask_coverage")):
        facts.append(f"mask coverage {entry['mask_coverage']:.1%}")
    return "; ".join(facts)


def _figure(src: str, stem: str, size: tuple[int, int] | None) -> str:
    dims = f' width="{size[0]}" height="{size[1]}"' if size else ""
    return (f'<figure><img src="{src}" alt="panels of frame {_e(stem)}"{dims}>'
            f"<figcaption>frame {_e(stem)}</figcaption></figure>")


def _drawn_panels(folder: Path, name: str, manifest: dict, frames: int, parts: list[str]) -> list[str]:
    """Figures of panels drawn from the saved maps (``panels`` not saved), embedded as JPEG; a note saying so goes
    into ``parts``."""
    drawn = draw_panels(folder, (manifest.get("spec") or {}).get("input") or {}, frames)
    if drawn is None:
        parts.append('<p class="note">No panels: the run saved neither panels nor masks, saliency or ED '
                     "(output.save).</p>")
        return []
    over = "over the input frames" if drawn.with_frames else "(the input frames could not be read from input.path)"
    parts.append(f'<p class="note">Panels were not saved (add <code>panels</code> to output.save): these are drawn '
                 f"by the report from the saved {_and(drawn.maps)} {over}; the ED scale is each frame's own 95th "
                 f"percentile, at least {ED_PANEL_FLOOR_PX:g} px.</p>")
    figures = []
    for stem, image in drawn.images:
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
        if ok:
            src = "data:image/jpeg;base64," + base64.b64encode(jpeg.tobytes()).decode()
            figures.append(_figure(src, stem, (image.shape[1], image.shape[0])))
    return figures


# -- small helpers ---------------------------------------------------------------------------------------------
def _e(value) -> str:
    return html.escape("" if value is None else str(value))


def _and(names: list[str]) -> str:
    return " and ".join(filter(None, (", ".join(names[:-1]), names[-1]))) if names else ""


def _mark(present: bool) -> str:
    return "<td>&#10003;</td>" if present else "<td></td>"


def _url(*parts: str) -> str:
    return "/".join(quote(p) for p in parts)


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _num(value, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if _finite(value) else _DASH


def _stat(entry: dict, metric: str, stat: str):
    value = entry.get(metric)
    return value.get(stat) if isinstance(value, dict) else None


def _png_size(path: Path) -> tuple[int, int] | None:
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.size
    except OSError:
        return None
