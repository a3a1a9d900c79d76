"""Fusion stages: appearance features and the motion map to the foreground probability."""

from eponet.core.params import Param


def window_problems(params: dict) -> list[str]:
    """The spec problem of a fusion stage's ``window`` / ``overlap`` parameters (the run engine's overlapping
    windows need fewer shared frames than a window holds); ``[]`` when they fit.

    >>> window_problems({"window": 8, "overlap": 8})
    ['overlap: expected fewer frames than window (8), got 8']
    >>> window_problems({"window": None, "overlap": 8})
    []
    """
    window = params.get("window")
    if window is not None and params["overlap"] >= window:
        return [f"overlap: expected fewer frames than window ({window}), got {params['overlap']}"]
    return []


def example_params(prefix: str, of: str) -> tuple[Param, ...]:
    """The parameters of a self-training's examples and fit (:func:`eponet.fusion.selftrain.self_trained_probability`),
    named with ``prefix``; ``of`` names the map whose values they threshold. One set for the ``selftrain`` fusion and
    for the ``convgru`` fusion's ``selftrain_*``."""
    return (
        Param(f"{prefix}foreground", "float", 0.9, f"{of} above which a pixel is a foreground example",
              minimum=0.0, maximum=1.0),
        Param(f"{prefix}background", "float", 0.05, f"{of} below which a pixel is a background example",
              minimum=0.0, maximum=1.0),
        Param(f"{prefix}foreground_share", "float", 0.0, f"where fewer than this share of a window's cells are above "
              f"{prefix}foreground, its top share of cells are the foreground examples (0 = never)",
              minimum=0.0, maximum=1.0),
        Param(f"{prefix}foreground_floor", "float", 0.5, f"{of} below which a cell is never a foreground example, "
              f"even with {prefix}foreground_share", minimum=0.0, maximum=1.0),
        Param(f"{prefix}l2", "float", 1e-3, "L2 penalty of the logistic regression", minimum=0.0),
        Param(f"{prefix}samples", "int", 60000, "at most this many training cells per window (half per class); its "
              "cost grows with them", minimum=2),
    )


def threshold_problems(params: dict, prefix: str = "") -> list[str]:
    """The spec problems of a self-training's confidence thresholds (``background`` below ``foreground``, and
    below ``foreground_floor`` when ``foreground_share`` lowers the foreground threshold); parameter names carry
    ``prefix``; ``[]`` when they fit.

    >>> threshold_problems({"foreground": 0.5, "background": 0.6, "foreground_share": 0.0, "foreground_floor": 0.5})
    ['background: expected a threshold below foreground (0.5), got 0.6']
    >>> threshold_problems({"st_foreground": 0.8, "st_background": 0.1, "st_foreground_share": 0.03,
    ...                     "st_foreground_floor": 0.05}, "st_")
    ['st_foreground_floor: expected a threshold above st_background (0.1), got 0.05']
    """
    foreground, background = params[prefix + "foreground"], params[prefix + "background"]
    if background >= foreground:
        return [f"{prefix}background: expected a threshold below {prefix}foreground ({foreground}), got {background}"]
    floor = params[prefix + "foreground_floor"]
    if params[prefix + "foreground_share"] > 0 and floor <= background:
        return [f"{prefix}foreground_floor: expected a threshold above {prefix}background ({background}), got {floor}"]
    return []
