"""Evaluation reports: the paper's Table 2 and Table 3 as text, JSON and CSV files, and a per-sequence bar chart."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..core.io import atomic_path, atomic_write_bytes

__all__ = [
    "TABLE3_ATTRIBUTES",
    "format_summary_table",
    "format_sequence_table",
    "format_attribute_table",
    "format_report",
    "write_json",
    "write_csv",
    "write_bar_chart",
    "default_chart_path",
]

#: The attributes of the EpO paper's Table 3, in its order.
TABLE3_ATTRIBUTES = ("AC", "DB", "FM", "MB", "OCC")

_ARROWS = {"mean": "↑", "recall": "↑", "decay": "↓"}
_STAT_NAMES = {"mean": "Mean", "recall": "Recall", "decay": "Decay"}


def _fmt(value: Any, width: int = 7) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-".rjust(width)
    return f"{value:.3f}".rjust(width)


def _metrics_of(overall: Mapping) -> list[str]:
    """The measures that were computed (a measure whose every statistic is missing, e.g. T with --no-t, is not)."""
    return [m for m in ("J", "F", "T") if isinstance(overall.get(m), Mapping)
            and any(overall[m].get(s) is not None for s in ("mean", "recall", "decay"))]


def format_summary_table(result: Mapping, method: str = "eponet") -> str:
    """The data-set means shaped like the paper's Table 2: measures as rows, the method as a column."""
    overall = result["overall"]
    name_w = max(len(method), 7)
    lines = [f"{'Measure':<14}{method:>{name_w}}"]
    lines.append("-" * (14 + name_w))
    for metric in _metrics_of(overall):
        arrow_t = "↓" if metric == "T" else None
        for k, stat in enumerate(("mean", "recall", "decay")):
            if stat not in overall[metric]:
                continue
            label = f"{metric if k == 0 else ' '}  {_STAT_NAMES[stat]} {arrow_t or _ARROWS[stat]}"
            lines.append(f"{label:<14}{_fmt(overall[metric][stat], name_w)}")
    if isinstance(overall.get("JF"), Mapping):
        lines.append(f"{'J&F Mean ↑':<14}{_fmt(overall['JF'].get('mean'), name_w)}")
    if result.get("dataset") in ("segtrackv2",) and overall.get("J", {}).get("frame_mean") is not None:
        lines.append(f"{'IoU (frames)':<14}{_fmt(overall['J']['frame_mean'], name_w)}")
    return "\n".join(lines)


def format_sequence_table(result: Mapping) -> str:
    """One row per sequence: J and F Mean/Recall/Decay and T Mean (whichever were computed)."""
    seqs = result["sequences"]
    columns: list[tuple[str, str, str]] = []
    overall = result["overall"]
    for metric in _metrics_of(overall):
        stats = ("mean",) if metric == "T" else ("mean", "recall", "decay")
        columns += [(metric, s, f"{metric}({s[0].upper() if s != 'recall' else 'O'})") for s in stats]
    name_w = max([8] + [len(s) for s in seqs])
    header = f"{'Sequence':<{name_w}}" + "".join(f"{c[2]:>8}" for c in columns)
    lines = [header, "-" * len(header)]
    for name, entry in seqs.items():
        row = f"{name:<{name_w}}"
        for metric, stat, _ in columns:
            row += _fmt((entry.get(metric) or {}).get(stat), 8)
        lines.append(row)
    lines.append("-" * len(header))
    row = f"{'Average':<{name_w}}"
    for metric, stat, _ in columns:
        row += _fmt(overall[metric].get(stat), 8)
    lines.append(row)
    return "\n".join(lines)


def format_attribute_table(result: Mapping, attributes: Sequence[str] = TABLE3_ATTRIBUTES) -> str:
    """The paper's Table 3: per attribute, mean J over sequences with it, without it, and the change."""
    table = result.get("attributes") or {}
    attrs = [a for a in attributes if a in table]
    if not attrs:
        return ""
    lines = [f"{'Attribute':<12}" + "".join(f"{a:>8}" for a in attrs)]
    lines.append("-" * len(lines[0]))
    for key, label in (("with", "J with"), ("without", "J without"), ("change", "change")):
        lines.append(f"{label:<12}" + "".join(_fmt(table[a].get(key), 8) for a in attrs))
    lines.append(f"{'sequences':<12}" + "".join(f"{table[a].get('n_with', 0):>8d}" for a in attrs))
    return "\n".join(lines)


def format_report(result: Mapping, method: str = "eponet", per_sequence: bool = True) -> str:
    """The text the CLI prints: per-sequence table, Table 2 summary and (DAVIS) the Table 3 attributes."""
    parts = [f"{result.get('dataset', '')}: {result['overall'].get('n_sequences', len(result['sequences']))} "
             f"sequences, results {result.get('results', '')}"]
    if per_sequence:
        parts.append(format_sequence_table(result))
    parts.append(format_summary_table(result, method))
    attr = format_attribute_table(result)
    if attr:
        parts.append(attr)
    return "\n\n".join(parts) + "\n"


def _json_safe(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return _json_safe(value.item())
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(result: Mapping, path: str | Path) -> Path:
    """Write the result as JSON (NaN as null) atomically."""
    path = Path(path)
    text = json.dumps(_json_safe(result), indent=2, allow_nan=False, ensure_ascii=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
    return path


def write_csv(result: Mapping, path: str | Path) -> Path:
    """Write one row per sequence (and a final ``Average`` row) as CSV, atomically."""
    path = Path(path)
    overall = result["overall"]
    columns = []
    for metric in _metrics_of(overall):
        stats = ("mean",) if metric == "T" else ("mean", "recall", "decay")
        columns += [(metric, s) for s in stats]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["sequence"] + [f"{m}_{s}" for m, s in columns] + ["n_frames"])

    def cell(v):
        return "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.6f}"

    for name, entry in result["sequences"].items():
        writer.writerow([name] + [cell((entry.get(m) or {}).get(s)) for m, s in columns]
                        + [entry.get("n_frames", "")])
    writer.writerow(["Average"] + [cell(overall[m].get(s)) for m, s in columns] + [overall.get("n_frames", "")])
    atomic_write_bytes(path, buf.getvalue().encode("utf-8"))
    return path


def default_chart_path(json_path: str | Path) -> Path:
    """Where the bar chart goes when only the JSON path is given: ``out.json`` -> ``out.png``."""
    return Path(json_path).with_suffix(".png")


def write_bar_chart(result: Mapping, path: str | Path, title: str | None = None) -> Path:
    """Per-sequence bar chart of mean J and F (dashed lines: data-set means), PNG, atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    seqs = list(result["sequences"].items())
    names = [n for n, _ in seqs]
    metrics = [m for m in ("J", "F") if any(isinstance(e.get(m), Mapping) for _, e in seqs)]
    width = max(6.0, 0.35 * len(names) + 2.0)
    fig = Figure(figsize=(width, 4.2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    colours = {"J": "#1f77b4", "F": "#ff7f0e"}
    bar_w = 0.8 / max(1, len(metrics))
    xs = range(len(names))
    for k, metric in enumerate(metrics):
        values = [((e.get(metric) or {}).get("mean") or 0.0) for _, e in seqs]
        ax.bar([x - 0.4 + bar_w * (k + 0.5) for x in xs], values, bar_w, label=f"{metric} mean", color=colours[metric])
        mean = (result["overall"].get(metric) or {}).get("mean")
        if mean is not None:
            ax.axhline(mean, color=colours[metric], linestyle="--", linewidth=1,
                       label=f"{metric} overall {mean:.3f}")
    ax.set_xticks(list(xs))
    ax.set_xticklabels(names, rotation=60, ha="right", fontsize=8)
    ax.set_ylim(0, 1.2)
    ax.set_yticks([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    ax.set_ylabel("score")
    ax.set_title(title or f"{result.get('dataset', '')}: per-sequence J and F")
    ax.legend(loc="upper center", ncol=4, fontsize=8, frameon=False)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
