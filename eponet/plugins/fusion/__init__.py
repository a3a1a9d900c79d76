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
