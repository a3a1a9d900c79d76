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


def threshold_problems(params: dict, foreground: str = "foreground", background: str = "background") -> list[str]:
    """The spec problem of a self-training's confidence thresholds (the ``background`` parameter must be below the
    ``foreground`` one); ``[]`` when they fit.

    >>> threshold_problems({"foreground": 0.5, "background": 0.6})
    ['background: expected a threshold below foreground (0.5), got 0.6']
    """
    if params[background] >= params[foreground]:
        return [f"{background}: expected a threshold below {foreground} ({params[foreground]}), got {params[background]}"]
    return []
