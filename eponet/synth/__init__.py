"""RBSF-style synthetic videos (real photographs on 3D planes, moving sprites) with exact ground truth."""

from .clip import Clip, generate_clip
from .scene import Scene, SceneConfig, Surface, sample_scene
from .textures import BUNDLED_PHOTOS, TextureBank
from .writer import sequence_seed, write_clip, write_dataset, write_index

__all__ = [
    "BUNDLED_PHOTOS",
    "Clip",
    "Scene",
    "SceneConfig",
    "Surface",
    "TextureBank",
    "generate_clip",
    "sample_scene",
    "sequence_seed",
    "write_clip",
    "write_dataset",
    "write_index",
]
