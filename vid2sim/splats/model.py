"""The Gaussian-splat scene: a dataclass of torch tensors (see docs/splat_renderer.md)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from .sh import num_sh_coeffs, rgb_to_sh0, sh_degree_from_coeffs

PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh")


@dataclass
class GaussianModel:
    """N Gaussians: means [N,3], quats [N,4] (w,x,y,z), log_scales [N,3],
    opacity_logits [N], sh [N,K,3] with K = (deg+1)^2 and sh[:, 0] the DC term."""

    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4]
    log_scales: torch.Tensor  # [N, 3]
    opacity_logits: torch.Tensor  # [N]
    sh: torch.Tensor  # [N, K, 3]

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expect = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
        for name, shape in expect.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"GaussianModel.{name} must be {shape}, got {tuple(getattr(self, name).shape)}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"GaussianModel.sh must be [N, K, 3], got {tuple(self.sh.shape)}")
        sh_degree_from_coeffs(self.sh.shape[1])

    # ---- derived quantities -------------------------------------------------
    @property
    def num(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_coeffs(self.sh.shape[1])

    @property
    def opacities(self) -> torch.Tensor:  # [N]
        return torch.sigmoid(self.opacity_logits)

    @property
    def scales(self) -> torch.Tensor:  # [N, 3]
        return torch.exp(self.log_scales)

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    # ---- construction ---------------------------------------------------------
    @classmethod
    def from_points(cls, xyz, rgb, sh_degree: int = 3, opacity: float = 0.1,
                    dtype: torch.dtype = torch.float32) -> "GaussianModel":
        """Isotropic Gaussians at points xyz [M,3] with colours rgb [M,3]
        (uint8 0..255 or float 0..1); scale = mean distance to the 3 nearest neighbours."""
        from scipy.spatial import cKDTree

        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        rgb = np.asarray(rgb)
        if rgb.shape != xyz.shape:
            raise ValueError(f"from_points: rgb {rgb.shape} does not match xyz {xyz.shape}")
        rgb = rgb.astype(np.float64) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float64)
        m = xyz.shape[0]
        if m >= 2:
            k = min(4, m)
            dist, _ = cKDTree(xyz).query(xyz, k=k)  # [M, k]; column 0 is the point itself
            scale = np.maximum(dist[:, 1:].mean(axis=1), 1e-7)
        else:
            scale = np.full(m, 0.01)
        sh = torch.zeros(m, num_sh_coeffs(sh_degree), 3, dtype=dtype)
        sh[:, 0] = rgb_to_sh0(torch.as_tensor(rgb, dtype=dtype))
        quats = torch.zeros(m, 4, dtype=dtype)
        quats[:, 0] = 1.0
        logit = float(np.log(opacity / (1.0 - opacity)))
        return cls(
            means=torch.as_tensor(xyz, dtype=dtype),
            quats=quats,
            log_scales=torch.as_tensor(np.log(scale), dtype=dtype)[:, None].repeat(1, 3),
            opacity_logits=torch.full((m,), logit, dtype=dtype),
            sh=sh,
        )

    @classmethod
    def empty(cls, sh_degree: int = 3, dtype: torch.dtype = torch.float32) -> "GaussianModel":
        k = num_sh_coeffs(sh_degree)
        z = lambda *s: torch.zeros(*s, dtype=dtype)  # noqa: E731
        return cls(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, k, 3))

    # ---- tensor plumbing ------------------------------------------------------
    def params(self) -> dict[str, torch.Tensor]:
        """name -> tensor (the same objects, for optimisers)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def _map(self, fn) -> "GaussianModel":
        return GaussianModel(**{k: fn(v) for k, v in self.params().items()})

    def clone(self) -> "GaussianModel":
        return self._map(lambda t: t.clone())

    def detach(self) -> "GaussianModel":
        return self._map(lambda t: t.detach())

    def to(self, *args, **kwargs) -> "GaussianModel":
        """Like Tensor.to (dtype and/or device)."""
        return self._map(lambda t: t.to(*args, **kwargs))

    def requires_grad_(self, flag: bool = True) -> "GaussianModel":
        for t in self.params().values():
            t.requires_grad_(flag)
        return self

    def index(self, mask: torch.Tensor) -> "GaussianModel":
        """Subset by boolean mask [N] or index tensor (new, detached tensors)."""
        return self._map(lambda t: t.detach()[mask])

    @staticmethod
    def cat(models: list["GaussianModel"]) -> "GaussianModel":
        """Concatenate models (same SH degree) into new, detached tensors."""
        if not models:
            raise ValueError("GaussianModel.cat needs at least one model")
        degrees = {m.sh_degree for m in models}
        if len(degrees) != 1:
            raise ValueError(f"GaussianModel.cat: mixed SH degrees {sorted(degrees)}")
        return GaussianModel(**{name: torch.cat([getattr(m, name).detach() for m in models])
                                for name in PARAM_NAMES})

    def with_sh_degree(self, degree: int) -> "GaussianModel":
        """Copy with SH truncated or zero-padded to `degree`."""
        k = num_sh_coeffs(degree)
        sh = self.sh.detach()
        if sh.shape[1] >= k:
            sh = sh[:, :k].clone()
        else:
            sh = torch.cat([sh, sh.new_zeros(self.num, k - sh.shape[1], 3)], dim=1)
        return GaussianModel(self.means.detach().clone(), self.quats.detach().clone(),
                             self.log_scales.detach().clone(),
                             self.opacity_logits.detach().clone(), sh)
