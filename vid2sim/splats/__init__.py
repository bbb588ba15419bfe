"""Gaussian-splat engine: model, cameras, PLY I/O and one render call over three backends."""

from .camera import Camera, look_at
from .model import GaussianModel
from .ply import read_ply, write_ply
from .render import get_backend, render
from .types import RasterOutput, RasterSettings, RenderOutput

__all__ = ["GaussianModel", "Camera", "RasterSettings", "RasterOutput", "RenderOutput",
           "render", "get_backend", "read_ply", "write_ply", "look_at"]
