"""gsplat-backed rasteriser (CUDA only): same signature and outputs as reference.rasterize.

gsplat is imported inside the functions, and only when CUDA is present, so the CPU
path never triggers gsplat's JIT CUDA build. Install with `pip install -e .[cuda]`.

What comes from where:
- culling, means2d, radii, colours (SH) and normals: `reference.project` (per-splat
  torch ops, cheap on the GPU), so near/far, covariance culling and normals follow the spec;
- color/normal/depth accumulations and alpha: gsplat `rasterization()` on the visible
  splats, with colours+normals as 6 feature channels and render_mode "RGB+D";
- median depth: gsplat `rasterize_to_indices_in_range` lists the contributing
  (splat, pixel) pairs, then the spec's transmittance rule is evaluated in torch.
Known differences from the spec (gsplat 1.5 kernels): alpha is clamped at 0.999
(not 0.99) and there is no sigma > 4.5 cutoff (the opacity-aware radius bounds
each splat instead); tests compare on scenes where these do not bite.
"""

from __future__ import annotations

import torch

from .camera import Camera
from .reference import ALPHA_MAX, ALPHA_MIN, MEDIAN_T, SIGMA_CUTOFF, T_MIN, check_camera, project
from .types import RasterOutput, RasterSettings

GSPLAT_VERSION = "1.5.3"
GSPLAT_TILE = 16  # px, gsplat's usual tile edge (RasterSettings.tile_size None)


def require_gsplat():
    """Import gsplat; clear errors when CUDA or gsplat is missing."""
    if not torch.cuda.is_available():
        raise RuntimeError("splat backend 'cuda' needs CUDA, which is not available")
    try:
        import gsplat
    except ImportError as exc:
        raise ImportError(f"splat backend 'cuda' needs gsplat=={GSPLAT_VERSION}: "
                          "pip install -e '.[cuda]'") from exc
    return gsplat


def rasterize(means, quats, log_scales, opacity_logits, sh, camera: Camera,
              settings: RasterSettings, absgrad: bool = False) -> RasterOutput:
    """Render on the GPU (inputs on any device; outputs on the device of `means`)."""
    gsplat = require_gsplat()
    check_camera(camera, settings)
    home, dtype, N = means.device, means.dtype, means.shape[0]
    W, H = settings.width, settings.height
    dev = torch.device("cuda")
    p = [t.to(dev, torch.float32) for t in (means, quats, log_scales, opacity_logits, sh)]
    proj = project(*p, camera, settings)
    ids = proj.ids
    if ids.numel() == 0:  # nothing visible: the reference handles this trivially
        from .reference import rasterize as reference_rasterize
        return reference_rasterize(means, quats, log_scales, opacity_logits, sh, camera,
                                   settings, absgrad=absgrad)
    viewmat = camera.world_to_cam.to(dev, torch.float32)[None]  # [1, 4, 4]
    K = camera.K.to(dev, torch.float32)[None]  # [1, 3, 3]
    feats = torch.cat([proj.colors, proj.normals], dim=-1)  # [V, 6]
    colors, alphas, meta = gsplat.rasterization(
        p[0][ids], p[1][ids], torch.exp(p[2][ids]), proj.opacities, feats, viewmat, K, W, H,
        near_plane=settings.near, far_plane=settings.far, radius_clip=0.0, eps2d=0.3,
        sh_degree=None, packed=False, tile_size=settings.tile(GSPLAT_TILE), render_mode="RGB+D",
        absgrad=absgrad, rasterize_mode="classic")
    img = colors[0]  # [H, W, 7]: rgb, normal, accumulated depth

    grad2d = means.new_zeros(N, 2)
    absgrad_buf = means.new_zeros(N, 2) if absgrad else None
    m2d = meta["means2d"]  # [1, V, 2]
    if m2d.requires_grad:
        m2d.register_hook(_grad_hook(m2d, grad2d, absgrad_buf, ids.to(home)))

    median = _median_depth(gsplat, meta, proj.depths, W, H)
    means2d_out = means.new_zeros(N, 2)
    means2d_out[ids.to(home)] = proj.means2d.detach().to(home, dtype)
    radii = torch.zeros(N, dtype=torch.int32, device=home)
    radii[ids.to(home)] = proj.radii.to(home)
    out = lambda t: t.to(home, dtype)  # noqa: E731
    return RasterOutput(
        color_accum=out(img[..., 0:3]), alpha=out(alphas[0, ..., 0]),
        depth_accum=out(img[..., 6]), normal_accum=out(img[..., 3:6]),
        median_depth=out(median), means2d=means2d_out, radii=radii,
        absgrad=absgrad_buf, grad2d=grad2d)


def _grad_hook(m2d: torch.Tensor, grad2d: torch.Tensor, absgrad_buf, ids: torch.Tensor):
    """Copy gsplat's dL/dmeans2d (and means2d.absgrad, set by its backward) into the buffers."""

    def hook(g):
        if g is None:
            return
        grad2d.index_add_(0, ids, g[0].detach().to(grad2d))
        if absgrad_buf is not None and getattr(m2d, "absgrad", None) is not None:
            absgrad_buf.index_add_(0, ids, m2d.absgrad[0].detach().to(absgrad_buf))

    return hook


def _median_depth(gsplat, meta: dict, depths: torch.Tensor, W: int, H: int) -> torch.Tensor:
    """Per-pixel z of the first splat after which T <= 0.5 ([H, W]; grad to that z only)."""
    from gsplat import rasterize_to_indices_in_range

    with torch.no_grad():
        T0 = torch.ones(1, H, W, device=depths.device)
        gs, pix, _ = rasterize_to_indices_in_range(
            0, 1 << 30, T0, meta["means2d"].detach(), meta["conics"], meta["opacities"],
            W, H, meta["tile_size"], meta["isect_offsets"], meta["flatten_ids"])
        gs, pix = gs.long(), pix.long()
        median = torch.zeros(H * W, dtype=depths.dtype, device=depths.device)
        if gs.numel() == 0:
            return median.reshape(H, W)
        # front-to-back order inside each pixel (depth ascending, ties by splat index)
        order = torch.argsort(gs, stable=True)  # gs indexes depth-sorted visible splats
        gs, pix = gs[order], pix[order]
        order = torch.argsort(pix, stable=True)
        gs, pix = gs[order], pix[order]
        xy = torch.stack([(pix % W).float() + 0.5, (pix // W).float() + 0.5], dim=-1)
        d = xy - meta["means2d"][0, gs].detach()
        a, b, c = meta["conics"][0, gs].unbind(-1)
        sigma = 0.5 * (a * d[:, 0] ** 2 + c * d[:, 1] ** 2) + b * d[:, 0] * d[:, 1]
        alpha = torch.clamp_max(meta["opacities"][0, gs] * torch.exp(-sigma), ALPHA_MAX)
        alpha = torch.where((sigma >= 0) & (sigma <= SIGMA_CUTOFF) & (alpha >= ALPHA_MIN),
                            alpha, torch.zeros_like(alpha))
        log_t = torch.log1p(-alpha)
        csum = torch.cumsum(log_t, 0)
        start = torch.searchsorted(pix, pix)  # first entry of each pixel's run
        before = torch.where(start > 0, csum[(start - 1).clamp_min(0)], torch.zeros_like(csum))
        T_after = torch.exp(csum - before)
        hit = (T_after <= MEDIAN_T) & (T_after >= T_MIN)
        pos = torch.arange(gs.numel(), device=gs.device)
        first = torch.full((H * W,), gs.numel(), dtype=torch.long, device=gs.device)
        first.scatter_reduce_(0, pix[hit], pos[hit], reduce="amin")
        has = first < gs.numel()
    return median.index_put((has.nonzero().squeeze(1),), depths[gs[first[has]]]).reshape(H, W)


def render_batch(scenes: list, cameras: list[Camera], scene_ids: list[int],
                 settings: RasterSettings, background=(0.0, 0.0, 0.0)) -> dict[str, torch.Tensor]:
    """Env frames of N cameras on the GPU: one gsplat call per scene with all of that scene's
    cameras batched (viewmats [C, 4, 4], Ks [C, 3, 3]); the CPU twin is
    `cpu.env_batch.SceneBatch.render`. scenes are GaussianModels; camera i sees
    scenes[scene_ids[i]]. Returns rgb [N, H, W, 3], alpha [N, H, W], depth [N, H, W]
    (expected camera z, 0 where empty), all on the GPU.

    Tested only where a GPU is present (tests/test_splats_cuda.py skips without CUDA); covariance
    culling is not applied on this path (gsplat has no max-norm 2D covariance cull)."""
    gsplat = require_gsplat()
    if settings.cov_cull_alpha is not None:
        raise NotImplementedError("cuda render_batch: cov_cull_alpha is not supported")
    dev, W, H, N = torch.device("cuda"), settings.width, settings.height, len(cameras)
    rgb = torch.zeros(N, H, W, 3, device=dev)
    alpha = torch.zeros(N, H, W, device=dev)
    depth = torch.zeros(N, H, W, device=dev)
    bg = torch.as_tensor(background, dtype=torch.float32, device=dev).reshape(3)
    ids = torch.as_tensor(scene_ids)
    for s, model in enumerate(scenes):
        rows = torch.nonzero(ids == s).squeeze(1)  # cameras of scene s
        if rows.numel() == 0:
            continue
        viewmats = torch.stack([cameras[i].world_to_cam for i in rows.tolist()]).to(dev, torch.float32)
        Ks = torch.stack([cameras[i].K for i in rows.tolist()]).to(dev, torch.float32)
        m = model.to(dev, torch.float32)
        deg = min(settings.active_sh_degree, m.sh_degree)
        colors, alphas, _ = gsplat.rasterization(
            m.means, torch.nn.functional.normalize(m.quats, dim=-1), torch.exp(m.log_scales),
            torch.sigmoid(m.opacity_logits), m.sh[:, :(deg + 1) ** 2], viewmats, Ks, W, H,
            near_plane=settings.near, far_plane=settings.far, eps2d=0.3, sh_degree=deg,
            tile_size=settings.tile(GSPLAT_TILE), render_mode="RGB+ED", rasterize_mode="classic")
        a = alphas[..., 0]  # [C, H, W]
        rgb[rows] = colors[..., :3] + (1.0 - a[..., None]) * bg
        alpha[rows] = a
        depth[rows] = torch.where(a > 0, colors[..., 3], torch.zeros_like(a))
    return {"rgb": rgb, "alpha": alpha, "depth": depth}
