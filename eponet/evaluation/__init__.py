"""Evaluation: the DAVIS J / F / T measures, data-set loaders, and reports (tables, JSON, CSV, bar chart).

The programmatic entry point is :func:`evaluate`; ``python -m eponet.evaluate`` is its command line.
"""

from .datasets import DATASETS, Dataset, SequenceGT, load_dataset, locate_results, read_ground_truth
from .evaluator import evaluate, evaluate_dataset
from .metrics import (
    T_SCALE,
    boundary_f_matrix,
    boundary_precision_recall,
    boundary_tolerance,
    db_eval_boundary,
    db_eval_iou,
    db_eval_t,
    iou_matrix,
    seg2bmap,
)
from .report import (
    format_attribute_table,
    format_report,
    format_summary_table,
    write_bar_chart,
    write_csv,
    write_json,
)
from .stats import decay, decay_bins, mean, recall, sequence_statistics

__all__ = [
    # entry points
    "evaluate",
    "evaluate_dataset",
    # measures
    "db_eval_iou",
    "db_eval_boundary",
    "boundary_precision_recall",
    "boundary_tolerance",
    "seg2bmap",
    "db_eval_t",
    "T_SCALE",
    "iou_matrix",
    "boundary_f_matrix",
    # statistics
    "mean",
    "recall",
    "decay",
    "decay_bins",
    "sequence_statistics",
    # data sets
    "DATASETS",
    "Dataset",
    "SequenceGT",
    "load_dataset",
    "locate_results",
    "read_ground_truth",
    # reports
    "format_report",
    "format_summary_table",
    "format_attribute_table",
    "write_json",
    "write_csv",
    "write_bar_chart",
]
