"""eponet: salient motion segmentation with geometric constraints on dense trajectories (EpO-Net)."""

__version__ = "0.1.0"
__all__ = ["__version__"]
