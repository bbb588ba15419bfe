"""Real spherical harmonics as in the original 3DGS (degrees 0..3).

`eval_sh` reads SH coefficients [N, K, 3] and unit view directions [N, 3] and
returns the raw colour [N, 3] (callers add 0.5 and clamp at 0).
"""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
      -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def num_sh_coeffs(degree: int) -> int:
    """K = (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_degree_from_coeffs(k: int) -> int:
    """Inverse of num_sh_coeffs; ValueError when k is not 1, 4, 9 or 16."""
    for d in range(4):
        if num_sh_coeffs(d) == k:
            return d
    raise ValueError(f"{k} SH coefficients per channel is not (d+1)^2 for a degree d in 0..3")


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """SH basis values [N, (degree+1)^2] for unit directions dirs [N, 3]."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2.0 * zz - xx - yy), C2[3] * xz,
                C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3.0 * xx - yy), C3[1] * xy * z,
                C3[2] * y * (4.0 * zz - xx - yy),
                C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                C3[4] * x * (4.0 * zz - xx - yy), C3[5] * z * (xx - yy),
                C3[6] * x * (xx - 3.0 * yy)]
    return torch.stack(out, dim=-1)


def eval_sh(degree: int, sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Colour [N, 3] = sum_k basis_k(dirs) sh[:, k]; uses bands up to `degree` only.

    sh [N, K, 3] with K >= (degree+1)^2; dirs [N, 3] unit vectors.
    """
    k = num_sh_coeffs(degree)
    if sh.shape[1] < k:
        raise ValueError(f"eval_sh: degree {degree} needs {k} coefficients, got {sh.shape[1]}")
    basis = sh_basis(degree, dirs)  # [N, k]
    return (basis.unsqueeze(-1) * sh[:, :k, :]).sum(dim=1)


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """DC coefficient giving colour rgb (in [0, 1]) from every direction."""
    return (rgb - 0.5) / C0


def sh0_to_rgb(sh0: torch.Tensor) -> torch.Tensor:
    """Inverse of rgb_to_sh0."""
    return sh0 * C0 + 0.5
