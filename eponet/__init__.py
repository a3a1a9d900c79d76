"""eponet: salient motion segmentation with geometric constraints on dense trajectories (EpO-Net).

The Python API (:mod:`eponet.api`, imported on first use so that ``import eponet`` stays light):
:func:`run` runs a spec and returns its manifest, :func:`segment` segments one video into arrays.
"""

__version__ = "0.1.0"
__all__ = ["__version__", "run", "segment", "Segmentation"]


def __getattr__(name: str):
    if name in ("run", "segment", "Segmentation"):
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'eponet' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
