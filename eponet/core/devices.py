"""Where torch stages run: the ``device`` parameter (``auto``, ``cpu``, ``cuda``) as a torch device."""

from __future__ import annotations

__all__ = ["DEVICES", "torch_device"]

#: Values of a stage's ``device`` parameter.
DEVICES = ("auto", "cpu", "cuda")


def torch_device(name: str):
    """``torch.device`` for ``name``; ``auto`` is the GPU when one is available, else the CPU."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
