"""The public names of eponet.evaluation stay put; the evaluate: section of a run spec is validated."""

from __future__ import annotations

import eponet.evaluation as evaluation
from .evalkit import make_davis2016, moving_square, write_results

PUBLIC = {
    "evaluate", "evaluate_dataset",
    "db_eval_iou", "db_eval_boundary", "boundary_precision_recall", "boundary_tolerance", "seg2bmap", "db_eval_t",
    "T_SCALE", "iou_matrix", "boundary_f_matrix",
    "mean", "recall", "decay", "decay_bins", "sequence_statistics",
    "DATASETS", "Dataset", "SequenceGT", "load_dataset", "locate_results", "read_ground_truth",
    "format_report", "format_summary_table", "format_attribute_table", "write_json", "write_csv", "write_bar_chart",
}


def test_public_names():
    assert set(evaluation.__all__) == PUBLIC
    for name in PUBLIC:
        assert hasattr(evaluation, name), name


def test_cli_module_exposes_main():
    from eponet import evaluate as cli

    assert callable(cli.main)


def test_evaluate_accepts_the_pipeline_call(tmp_path):
    # the pipeline's evaluate: section calls evaluate(dataset, root=..., results=..., sequences=..., resolution=...,
    # compute_t=...) with the spec's dataset names, "fbms" and "generic" included
    seqs = {"alpha": moving_square(5)}
    root = make_davis2016(tmp_path / "D", seqs)
    results = write_results(tmp_path / "run", seqs)
    out = evaluation.evaluate("davis2016", root=root, results=results, sequences=["alpha"], resolution="480p",
                              compute_t=False)
    assert out["overall"]["J"]["mean"] == 1.0
    assert out["overall"]["T"]["mean"] is None
    for name in ("davis2016", "davis2017", "segtrackv2", "fbms", "generic"):
        from eponet.evaluation.datasets import canonical_dataset

        assert canonical_dataset(name) in evaluation.DATASETS
