"""Plain-PyTorch reference rasteriser: the executable form of docs/splat_renderer.md.

Written for clarity, not speed: per image tile, every visible splat whose square
[mean2d +- radius] touches the tile is evaluated at every pixel of the tile (dense
[P, V] tensors), and autograd provides all gradients. It is the ground truth the `cpu` and `cuda`
backends are tested against; it runs in float32 or float64 (for gradcheck), on the device of `means`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .camera import Camera
from .sh import eval_sh, sh_degree_from_coeffs
from .types import RasterOutput, RasterSettings

LOWPASS = 0.3  # screen-space dilation added to Sigma2d
FOV_CLAMP = 0.3  # gsplat's extra margin on the Jacobian clamp (fraction of half-width)
SIGMA_CUTOFF = 4.5  # 3-sigma ellipse: 0.5 * 3^2
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
MEDIAN_T = 0.5


def check_camera(camera: Camera, settings: RasterSettings) -> None:
    """ValueError when settings and camera disagree on the image size."""
    if (settings.width, settings.height) != (camera.width, camera.height):
        raise ValueError(f"RasterSettings size {settings.width}x{settings.height} differs from "
                         f"camera size {camera.width}x{camera.height}")


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] from quaternions [N, 4] (w, x, y, z), normalised here."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


@dataclass
class Projection:
    """Per-splat screen-space quantities for the visible splats `ids` (sorted by depth)."""

    ids: torch.Tensor  # [V] int64 indices into the model, ascending camera z
    depths: torch.Tensor  # [V] camera z
    means2d: torch.Tensor  # [V, 2] pixels
    conics: torch.Tensor  # [V, 3] (a, b, c) of Sigma2d^-1
    radii: torch.Tensor  # [V] int32
    colors: torch.Tensor  # [V, 3] clamped SH colour
    opacities: torch.Tensor  # [V]
    normals: torch.Tensor  # [V, 3] camera frame, facing the camera


def _jacobian(t: torch.Tensor, camera: Camera, width: int, height: int) -> torch.Tensor:
    """Perspective Jacobian [V, 2, 3] with gsplat's clamp of t_x/t_z and t_y/t_z."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    lim_xp = (width - cx) / fx + FOV_CLAMP * (0.5 * width / fx)
    lim_xn = cx / fx + FOV_CLAMP * (0.5 * width / fx)
    lim_yp = (height - cy) / fy + FOV_CLAMP * (0.5 * height / fy)
    lim_yn = cy / fy + FOV_CLAMP * (0.5 * height / fy)
    tx, ty, tz = t.unbind(-1)
    txc = tz * torch.clamp(tx / tz, -lim_xn, lim_xp)
    tyc = tz * torch.clamp(ty / tz, -lim_yn, lim_yp)
    zero = torch.zeros_like(tz)
    row0 = torch.stack([fx / tz, zero, -fx * txc / (tz * tz)], dim=-1)
    row1 = torch.stack([zero, fy / tz, -fy * tyc / (tz * tz)], dim=-1)
    return torch.stack([row0, row1], dim=-2)


def project(means, quats, log_scales, opacity_logits, sh, camera: Camera,
            settings: RasterSettings) -> Projection:
    """Steps 1-8 of the spec: cull, project and colour; returns the visible splats."""
    dtype = means.dtype
    W, H = settings.width, settings.height
    w2c = camera.world_to_cam.to(means.device, dtype)
    R_wc, t_wc = w2c[:3, :3], w2c[:3, 3]
    t_all = means @ R_wc.T + t_wc  # [N, 3]
    z = t_all[:, 2].detach()
    ids = torch.nonzero((z >= settings.near) & (z <= settings.far)).squeeze(1)

    t = t_all[ids]  # [V, 3]
    R = quat_to_rotmat(quats[ids])  # [V, 3, 3]
    M = R * torch.exp(log_scales[ids])[:, None, :]  # R S
    cov_cam = R_wc @ (M @ M.transpose(1, 2)) @ R_wc.T  # [V, 3, 3]
    J = _jacobian(t, camera, W, H)
    cov2d = J @ cov_cam @ J.transpose(1, 2) + LOWPASS * torch.eye(2, dtype=dtype, device=means.device)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    mean2d = torch.stack([camera.fx * t[:, 0] / t[:, 2] + camera.cx,
                          camera.fy * t[:, 1] / t[:, 2] + camera.cy], dim=-1)  # [V, 2]
    with torch.no_grad():
        lam = 0.5 * (a + c) + torch.sqrt((0.25 * (a - c) ** 2 + b * b).clamp_min(0))
        radius = torch.ceil(3.0 * torch.sqrt(lam.clamp_min(0)))
        ok = det > 0
        if settings.cov_cull_alpha is not None:
            ok &= cov2d.abs().amax(dim=(1, 2)) <= settings.cov_cull_alpha * H * W
        mx, my = mean2d[:, 0], mean2d[:, 1]
        ok &= ~((mx + radius <= 0) | (mx - radius >= W) | (my + radius <= 0) | (my - radius >= H))
        keep = torch.nonzero(ok).squeeze(1)
        order = torch.argsort(t[keep, 2], stable=True)
        keep = keep[order]

    ids = ids[keep]
    t, R, det = t[keep], R[keep], det[keep]
    a, b, c = a[keep], b[keep], c[keep]
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    degree = min(settings.active_sh_degree, sh_degree_from_coeffs(sh.shape[1]))
    dirs = torch.nn.functional.normalize(means[ids] - camera.center.to(means.device, dtype), dim=-1)
    colors = torch.clamp_min(eval_sh(degree, sh[ids], dirs) + 0.5, 0.0)

    axis = torch.argmin(log_scales[ids].detach(), dim=1)  # [V], first minimum on ties
    n_world = torch.gather(R, 2, axis[:, None, None].expand(-1, 3, 1)).squeeze(2)
    n_cam = n_world @ R_wc.T
    flip = ((n_cam * t).sum(-1) > 0).detach()
    normals = torch.where(flip[:, None], -n_cam, n_cam)

    return Projection(ids=ids, depths=t[:, 2], means2d=mean2d[keep], conics=conics,
                      radii=radius[keep].to(torch.int32), colors=colors,
                      opacities=torch.sigmoid(opacity_logits[ids]), normals=normals)


def _composite(pix: torch.Tensor, proj: Projection, m2d: torch.Tensor,
               offset: torch.Tensor | None) -> tuple[torch.Tensor, ...]:
    """Front-to-back compositing of the splats in `proj` (depth-sorted) at pixel
    centres pix [P, 2]; m2d [V, 2] are their means2d, offset [P, V, 2] or None."""
    d = pix[:, None, :] - m2d[None, :, :]  # [P, V, 2]
    if offset is not None:
        d = d - offset
    a, b, c = proj.conics.unbind(-1)
    sigma = 0.5 * (a * d[..., 0] ** 2 + c * d[..., 1] ** 2) + b * d[..., 0] * d[..., 1]
    alpha = torch.clamp_max(proj.opacities * torch.exp(-sigma), ALPHA_MAX)  # [P, V]
    valid = (sigma >= 0) & (sigma <= SIGMA_CUTOFF) & (alpha >= ALPHA_MIN)
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
    # Early stop: a splat that would push T below T_MIN and everything after it are dropped.
    with torch.no_grad():
        included = torch.cumprod(1.0 - alpha, dim=1) >= T_MIN
    alpha = torch.where(included, alpha, torch.zeros_like(alpha))
    T_after = torch.cumprod(1.0 - alpha, dim=1)  # [P, V]
    T_before = torch.cat([torch.ones_like(T_after[:, :1]), T_after[:, :-1]], dim=1)
    w = alpha * T_before  # [P, V]
    color = w @ proj.colors
    depth = w @ proj.depths
    normal = w @ proj.normals
    acc = 1.0 - torch.prod(1.0 - alpha, dim=1)
    median = torch.zeros_like(acc)
    if alpha.shape[1]:
        with torch.no_grad():
            crossed = T_after <= MEDIAN_T
            hit = crossed.any(dim=1)
            first = torch.argmax(crossed.to(torch.int8), dim=1)  # first crossing
        median = torch.where(hit, proj.depths[first], median)
    return color, acc, depth, normal, median


def _subset(proj: Projection, sel: torch.Tensor) -> Projection:
    return Projection(**{k: getattr(proj, k)[sel] for k in proj.__dataclass_fields__})


def _tiles(width: int, height: int, size: int):
    """(x0, x1, y0, y1) pixel ranges of size x size tiles covering the image."""
    for y0 in range(0, height, size):
        for x0 in range(0, width, size):
            yield x0, min(x0 + size, width), y0, min(y0 + size, height)


def pixel_centres(width: int, height: int, dtype: torch.dtype, device=None) -> torch.Tensor:
    """Pixel centres [H*W, 2] as (x, y) = (j + 0.5, i + 0.5), row-major."""
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype, device=device) + 0.5,
                            torch.arange(width, dtype=dtype, device=device) + 0.5, indexing="ij")
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)


def _accumulate_into(buf: torch.Tensor, ids: torch.Tensor, absolute: bool):
    """Backward hook adding a [V, 2] (or per-pixel [P, V, 2], summed of |.|) gradient
    into buf [N, 2] at rows ids; returns None so the gradient itself is unchanged."""

    def hook(g: torch.Tensor | None) -> None:
        if g is None:
            return
        g = g.detach()
        buf.index_add_(0, ids, g.abs().sum(0) if absolute else g)

    return hook


def rasterize(means, quats, log_scales, opacity_logits, sh, camera: Camera,
              settings: RasterSettings, absgrad: bool = False) -> RasterOutput:
    """Render raw accumulations (see RasterOutput); differentiable by autograd.

    After `loss.backward()`, `out.grad2d` holds dL/dmeans2d and (with absgrad=True)
    `out.absgrad` the AbsGS sum of per-pixel |dL_p/dmeans2d|; both [N, 2], zeros
    for culled splats.
    """
    check_camera(camera, settings)
    dtype, dev, N = means.dtype, means.device, means.shape[0]
    W, H = settings.width, settings.height
    proj = project(means, quats, log_scales, opacity_logits, sh, camera, settings)

    grad2d = means.new_zeros(N, 2)
    absgrad_buf = means.new_zeros(N, 2) if absgrad else None
    m2d = proj.means2d
    if m2d.requires_grad:
        m2d = m2d.view_as(m2d)  # own node, so the hook sees only the pixel path
        m2d.register_hook(_accumulate_into(grad2d, proj.ids, absolute=False))

    # Tiles only bound the work: a splat can reach a pixel only inside its square
    # [mean2d +- radius], so the result is the same for any tile size.
    pix_all = pixel_centres(W, H, dtype, means.device)  # [H*W, 2]
    with torch.no_grad():
        lo = proj.means2d.detach() - proj.radii[:, None].to(dtype)  # [V, 2]
        hi = proj.means2d.detach() + proj.radii[:, None].to(dtype)
    parts, where = [], []
    for x0, x1, y0, y1 in _tiles(W, H, max(1, settings.tile(16))):
        sel = torch.nonzero((lo[:, 0] < x1) & (hi[:, 0] > x0)
                            & (lo[:, 1] < y1) & (hi[:, 1] > y0)).squeeze(1)
        rows = (torch.arange(y0, y1, device=dev)[:, None] * W + torch.arange(x0, x1, device=dev)[None, :])
        rows = rows.reshape(-1)
        offset = None
        if absgrad and m2d.requires_grad and sel.numel():
            offset = torch.zeros(rows.numel(), sel.numel(), 2, dtype=dtype, device=dev, requires_grad=True)
            offset.register_hook(_accumulate_into(absgrad_buf, proj.ids[sel], absolute=True))
        parts.append(_composite(pix_all[rows], _subset(proj, sel), m2d[sel], offset))
        where.append(rows)
    where = torch.cat(where)
    color, acc, depth, normal, median = (
        torch.cat(p, dim=0).new_zeros((H * W,) + p[0].shape[1:]).index_copy(
            0, where, torch.cat(p, dim=0)) for p in zip(*parts))

    means2d_out = means.new_zeros(N, 2)
    means2d_out[proj.ids] = proj.means2d.detach()
    radii = torch.zeros(N, dtype=torch.int32, device=dev)
    radii[proj.ids] = proj.radii
    return RasterOutput(
        color_accum=color.reshape(H, W, 3), alpha=acc.reshape(H, W),
        depth_accum=depth.reshape(H, W), normal_accum=normal.reshape(H, W, 3),
        median_depth=median.reshape(H, W), means2d=means2d_out, radii=radii,
        absgrad=absgrad_buf, grad2d=grad2d)
