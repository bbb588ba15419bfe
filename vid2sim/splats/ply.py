"""Read and write the standard 3DGS PLY (binary little-endian, one `vertex` element).

The property list and its meaning are the bundle contract in `vid2sim.formats.splat_ply`
(normals written as zeros, optional on read; the quaternion need not be normalised). `read_ply`
checks the header first (`read_splat_header`: layout, the MAX_SPLATS cap, the body size), so a bad
file is a `BundleError` (`BundleTooLarge` over the cap) before any body byte is read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from vid2sim.formats.errors import BundleError
from vid2sim.formats.splat_ply import property_names, read_splat_header

from .model import GaussianModel


def write_ply(model: GaussianModel, path: str | Path) -> Path:
    """Write `model` to `path` (parent folders created; written via a temp file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m = model.detach().to(torch.float32)
    n = m.num
    sh = m.sh.numpy()  # [N, K, 3]
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # [N, 3*(K-1)] channel-major
    columns = np.concatenate([m.means.numpy(), np.zeros((n, 3), np.float32), sh[:, 0, :], rest,
                              m.opacity_logits.numpy()[:, None], m.log_scales.numpy(),
                              m.quats.numpy()], axis=1)
    names = property_names(m.sh.shape[1])
    data = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        data[name] = columns[:, i]
    tmp = path.with_name(path.name + ".tmp")
    PlyData([PlyElement.describe(data, "vertex")], text=False, byte_order="<").write(str(tmp))
    tmp.replace(path)
    return path


def read_ply(path: str | Path, dtype: torch.dtype = torch.float32) -> GaussianModel:
    """Read a 3DGS PLY of any SH degree 0..3 (normals optional); its header is checked first."""
    path = Path(path)
    header = read_splat_header(path)
    try:
        v = PlyData.read(str(path))["vertex"].data
    except Exception as exc:  # plyfile raises several types on malformed input
        raise BundleError(path, f"unreadable PLY ({type(exc).__name__}: {exc})") from exc
    rest_names = [f"f_rest_{i}" for i in range(sum(p.startswith("f_rest_") for p in header.properties))]
    k = len(rest_names) // 3 + 1

    def cols(props: list[str]) -> np.ndarray:
        return np.stack([np.asarray(v[p], dtype=np.float64) for p in props], axis=1) \
            if props else np.zeros((len(v), 0))

    n = len(v)
    sh = np.zeros((n, k, 3))
    sh[:, 0, :] = cols(["f_dc_0", "f_dc_1", "f_dc_2"])
    sh[:, 1:, :] = cols(rest_names).reshape(n, 3, k - 1).transpose(0, 2, 1)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    return GaussianModel(
        means=t(cols(["x", "y", "z"])),
        quats=t(cols(["rot_0", "rot_1", "rot_2", "rot_3"])),
        log_scales=t(cols(["scale_0", "scale_1", "scale_2"])),
        opacity_logits=t(cols(["opacity"])[:, 0]),
        sh=t(sh),
    )
