"""Fusion stages: appearance features and the motion map to the foreground probability."""


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


def threshold_problems(params: dict, prefix: str = "") -> list[str]:
    """The spec problems of a self-training's confidence thresholds (``background`` below ``foreground``, and
    below ``foreground_floor`` when ``foreground_share`` lowers the foreground threshold); parameter names carry
    ``prefix``; ``[]`` when they fit.

    >>> threshold_problems({"foreground": 0.5, "background": 0.6})
    ['background: expected a threshold below foreground (0.5), got 0.6']
    >>> threshold_problems({"st_foreground": 0.8, "st_background": 0.1, "st_foreground_share": 0.03,
    ...                     "st_foreground_floor": 0.05}, "st_")
    ['st_foreground_floor: expected a threshold above st_background (0.1), got 0.05']
    """
    foreground, background = params[prefix + "foreground"], params[prefix + "background"]
    if background >= foreground:
        return [f"{prefix}background: expected a threshold below {prefix}foreground ({foreground}), got {background}"]
    floor = params.get(prefix + "foreground_floor", 1.0)
    if params.get(prefix + "foreground_share", 0.0) > 0 and floor <= background:
        return [f"{prefix}foreground_floor: expected a threshold above {prefix}background ({background}), got {floor}"]
    return []
