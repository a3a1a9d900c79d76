"""The evaluation after a run (the spec's ``evaluate:`` section), plugged into core through ``eponet_evaluate``."""

from __future__ import annotations

from eponet.core.hookspecs import hookimpl

__all__ = ["eponet_evaluate"]


@hookimpl
def eponet_evaluate(spec, sequences):
    """Score the written masks against ground truth with :func:`eponet.evaluation.evaluate`."""
    from eponet.evaluation import evaluate

    options = spec.evaluate
    extra = {}
    root = options.get("root") or spec.input.path
    if options["dataset"] == "generic":  # ground-truth masks folder + the frames that were processed
        root, extra["frames"] = options.get("masks") or root, spec.input.path
    return evaluate(
        options["dataset"],
        root=root,
        results=spec.output.dir,
        sequences=sequences,
        resolution=options.get("resolution") or spec.input.resolution,
        compute_t=options.get("t", True),
        **extra,
    )
