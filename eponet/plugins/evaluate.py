"""The evaluation after a run (the spec's ``evaluate:`` section), plugged into core through ``eponet_evaluate``."""

from __future__ import annotations

from eponet.core.hookspecs import hookimpl

__all__ = ["eponet_evaluate", "eponet_evaluate_problems"]


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
        max_frames=spec.input.max_frames,
        **extra,
    )


@hookimpl
def eponet_evaluate_problems(options, input_path, resolution, sequences):
    """DAVIS: the annotation folder exists (else one line naming it and the resolutions there) and holds the
    input's sequences (a typo gets the nearest name)."""
    from eponet.core.errors import InputError
    from eponet.evaluation.datasets import canonical_dataset, load_dataset

    dataset = canonical_dataset(options["dataset"])
    if dataset not in ("davis2016", "davis2017"):
        return []
    wanted = options.get("resolution") or resolution
    if wanted != resolution and options.get("root") in (None, input_path):
        return [f"evaluate.resolution: masks are written at the input frames' size ({resolution}), so they cannot "
                f"be scored against the {wanted} annotations; drop evaluate.resolution or set input.resolution: {wanted}"]
    try:
        load_dataset(dataset, options.get("root") or input_path, sequences=sequences, resolution=wanted)
    except InputError as exc:
        return [f"evaluate: {exc}"]
    return []
