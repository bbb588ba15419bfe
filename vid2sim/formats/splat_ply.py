"""3DGS PLY: the property list of `splats.ply` (binary little-endian, one `vertex` element).

Properties, all float32: x y z [nx ny nz] f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2
rot_0..3. f_rest is channel-major (the K-1 higher-band coefficients of R, then G, then B);
opacity is the logit, scale_* the log-scales, rot_* the (w, x, y, z) quaternion. Normals are
written (zeros) but optional on read. `check_splats` reads a PLY and checks the layout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData

from vid2sim.formats.errors import BundleError

SPLATS_PLY = "splats.ply"
NORMAL_PROPERTIES = ("nx", "ny", "nz")
REQUIRED_PROPERTIES = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                       "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def property_names(n_sh_coeffs: int) -> list[str]:
    """Written property order for K = n_sh_coeffs SH coefficients per channel (normals included)."""
    rest = [f"f_rest_{i}" for i in range(3 * (n_sh_coeffs - 1))]
    return ["x", "y", "z", *NORMAL_PROPERTIES, "f_dc_0", "f_dc_1", "f_dc_2", *rest,
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def check_splats(path: Path) -> tuple[int, tuple[float, ...]]:
    """3DGS PLY -> (count, bounds [6]); raise BundleError when the layout is not 3DGS."""
    if not path.is_file():
        raise BundleError(path, "missing splats file")
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"]
    except KeyError:
        raise BundleError(path, "PLY has no 'vertex' element") from None
    except Exception as e:  # plyfile raises several types on malformed input
        raise BundleError(path, f"unreadable PLY ({type(e).__name__}: {e})") from None
    names = [p.name for p in vertex.properties]
    missing = [p for p in REQUIRED_PROPERTIES if p not in names]
    if missing:
        raise BundleError(path, f"PLY lacks 3DGS properties: {', '.join(missing)}")
    rest = sorted(int(n[7:]) for n in names if n.startswith("f_rest_") and n[7:].isdigit())
    if rest != list(range(len(rest))) or len(rest) % 3:
        raise BundleError(path, "f_rest_* properties must be f_rest_0..f_rest_{3k-1}")
    n = int(vertex.count)
    if n == 0:
        raise BundleError(path, "PLY holds no Gaussians")
    _check_values(path, vertex, names)
    xyz = np.stack([np.asarray(vertex[c], np.float64) for c in ("x", "y", "z")], 1)  # [N, 3]
    return n, tuple(float(v) for v in (*xyz.min(0), *xyz.max(0)))


def _check_values(path: Path, vertex, names: list[str]) -> None:
    """Every Gaussian parameter finite and every rotation quaternion non-zero."""
    groups = {"positions": ("x", "y", "z"), "opacities": ("opacity",), "scales": ("scale_0", "scale_1", "scale_2"),
              "rotations": ("rot_0", "rot_1", "rot_2", "rot_3"),
              "colours": tuple(n for n in names if n.startswith(("f_dc_", "f_rest_")))}
    for label, cols in groups.items():
        for c in cols:
            bad = int(np.count_nonzero(~np.isfinite(np.asarray(vertex[c], np.float64))))
            if bad:
                raise BundleError(path, f"non-finite splat {label}: {bad} NaN/inf value(s) in '{c}'")
    quat = np.stack([np.asarray(vertex[c], np.float64) for c in groups["rotations"]], 1)
    zero = int(np.count_nonzero(np.abs(quat).sum(1) == 0))
    if zero:
        raise BundleError(path, f"{zero} splat(s) with a zero rotation quaternion (rot_0..rot_3 all 0)")
