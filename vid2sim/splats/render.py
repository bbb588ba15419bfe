"""One render call over any backend: `render(model, camera) -> RenderOutput`.

Backends all implement `rasterize(means, quats, log_scales, opacity_logits, sh,
camera, settings, absgrad=False) -> RasterOutput` (docs/splat_renderer.md):
"torch" (reference.py), "cpu" (vid2sim.splats.cpu, numba), "cuda" (gsplat).
"""

from __future__ import annotations

import importlib
from typing import Callable, Sequence

import torch

from .camera import Camera
from .model import GaussianModel
from .types import RasterOutput, RasterSettings, RenderOutput

BACKENDS = ("torch", "cpu", "cuda")
Rasterize = Callable[..., RasterOutput]


def get_backend(name: str = "auto") -> Rasterize:
    """The rasterize function for `name`; "auto" = cuda if present, else cpu, else torch."""
    if name == "auto":
        for candidate in ("cuda", "cpu"):
            try:
                return get_backend(candidate)
            except (ImportError, RuntimeError):
                continue
        name = "torch"
    if name == "torch":
        from .reference import rasterize
        return rasterize
    if name == "cpu":
        return importlib.import_module("vid2sim.splats.cpu").rasterize
    if name == "cuda":
        if not torch.cuda.is_available():
            raise RuntimeError("splat backend 'cuda' needs CUDA, which is not available")
        from .cuda import rasterize
        from .cuda import require_gsplat
        require_gsplat()
        return rasterize
    raise ValueError(f"unknown splat backend {name!r}; choose from auto, {', '.join(BACKENDS)}")


def settings_for(camera: Camera, **overrides) -> RasterSettings:
    """RasterSettings sized for `camera`."""
    return RasterSettings(width=camera.width, height=camera.height, **overrides)


def finish(raw: RasterOutput, background: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0)
           ) -> RenderOutput:
    """Derived images from raw accumulations: rgb over background, depth, unit normals.
    Float32 CPU images take one numba pass each way (`cpu.finish`); others, and the reference
    the tests hold it to, `finish_reference`."""
    from .cpu.finish import finish_images, fused_applies

    images = (raw.color_accum, raw.alpha, raw.depth_accum, raw.normal_accum)
    if not fused_applies(*images):
        return finish_reference(raw, background)
    bg = torch.as_tensor(background, dtype=torch.float32).reshape(3)
    rgb, depth, normal = finish_images(*images, bg)
    return RenderOutput(rgb=rgb, alpha=raw.alpha, depth=depth, median_depth=raw.median_depth,
                        normal=normal, raw=raw)


def finish_reference(raw: RasterOutput, background: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0)
                     ) -> RenderOutput:
    """`finish` in torch ops (any device and dtype): the reference of the fused pass."""
    alpha = raw.alpha
    bg = torch.as_tensor(background, dtype=alpha.dtype, device=alpha.device).reshape(3)
    rgb = raw.color_accum + (1.0 - alpha)[..., None] * bg
    covered = alpha > 0
    depth = torch.where(covered, raw.depth_accum / alpha.clamp_min(1e-6),
                        torch.zeros_like(alpha))
    norm = raw.normal_accum.norm(dim=-1, keepdim=True)
    ok = covered[..., None] & (norm > 0)
    normal = torch.where(ok, raw.normal_accum / norm.clamp_min(1e-12),
                         torch.zeros_like(raw.normal_accum))
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, median_depth=raw.median_depth,
                        normal=normal, raw=raw)


def render(model: GaussianModel, camera: Camera, settings: RasterSettings | None = None,
           background: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0),
           backend: str = "auto", absgrad: bool = False) -> RenderOutput:
    """Render `model` from `camera`; reads the model tensors, returns [H, W, C] images.

    settings default to the camera's size with RasterSettings defaults.
    """
    settings = settings or settings_for(camera)
    raster = get_backend(backend)
    raw = raster(model.means, model.quats, model.log_scales, model.opacity_logits, model.sh,
                 camera, settings, absgrad=absgrad)
    return finish(raw, background)
