"""3DGS PLY: round trip, hand-written standard files (degree 0 and 3), bad files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from vid2sim.formats.errors import BundleError
from vid2sim.splats import GaussianModel, read_ply, write_ply


def random_model(n: int, degree: int) -> GaussianModel:
    g = torch.Generator().manual_seed(degree)
    return GaussianModel(torch.randn(n, 3, generator=g), torch.randn(n, 4, generator=g),
                         torch.randn(n, 3, generator=g), torch.randn(n, generator=g),
                         torch.randn(n, (degree + 1) ** 2, 3, generator=g))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_exact(tmp_path, degree):
    m = random_model(37, degree)
    path = write_ply(m, tmp_path / "sub" / "scene.ply")
    r = read_ply(path)
    for name, t in m.params().items():
        assert torch.equal(getattr(r, name), t), name
    ply = PlyData.read(str(path))
    assert ply.header.splitlines()[1] == "format binary_little_endian 1.0"
    names = [p.name for p in ply["vertex"].properties]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[-8:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert len(names) == 17 + 3 * ((degree + 1) ** 2 - 1)
    assert not (tmp_path / "sub" / "scene.ply.tmp").exists()


def _hand_written(path, n: int, degree: int, normals: bool = True, drop: str | None = None):
    """A PLY in the original 3DGS layout built column by column; returns the arrays."""
    rng = np.random.default_rng(degree)
    k = (degree + 1) ** 2
    cols = {"x": rng.normal(size=n), "y": rng.normal(size=n), "z": rng.normal(size=n)}
    if normals:
        cols.update(nx=np.zeros(n), ny=np.zeros(n), nz=np.zeros(n))
    dc = rng.normal(size=(n, 3))
    rest = rng.normal(size=(n, 3, k - 1))  # [N, channel, coeff]
    for c in range(3):
        cols[f"f_dc_{c}"] = dc[:, c]
    for c in range(3):
        for j in range(k - 1):
            cols[f"f_rest_{c * (k - 1) + j}"] = rest[:, c, j]  # channel-major, as 3DGS
    opacity, scales, rots = rng.normal(size=n), rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
    cols["opacity"] = opacity
    for i in range(3):
        cols[f"scale_{i}"] = scales[:, i]
    for i in range(4):
        cols[f"rot_{i}"] = rots[:, i]
    if drop:
        del cols[drop]
    data = np.empty(n, dtype=[(name, "f4") for name in cols])
    for name, v in cols.items():
        data[name] = v
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    f = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], 1)
    return f(xyz), f(dc), f(rest), f(opacity), f(scales), f(rots)


@pytest.mark.parametrize("degree,normals", [(0, True), (3, True), (3, False)])
def test_reads_hand_written_standard_layout(tmp_path, degree, normals):
    xyz, dc, rest, opacity, scales, rots = _hand_written(tmp_path / "g.ply", 11, degree, normals)
    m = read_ply(tmp_path / "g.ply")
    assert m.num == 11 and m.sh_degree == degree
    assert torch.equal(m.means, xyz) and torch.equal(m.quats, rots)
    assert torch.equal(m.log_scales, scales) and torch.equal(m.opacity_logits, opacity)
    assert torch.equal(m.sh[:, 0], dc)
    # coefficient j of channel c lives at sh[:, 1 + j, c]
    assert torch.equal(m.sh[:, 1:, :], rest.transpose(1, 2))
    if degree == 3:
        assert m.sh[4, 5, 2] == rest[4, 2, 4]


def test_missing_property_names_file_and_property(tmp_path):
    path = tmp_path / "broken.ply"
    _hand_written(path, 5, 1, drop="scale_1")
    with pytest.raises(BundleError, match=r"broken\.ply.*scale_1"):
        read_ply(path)


def test_bad_sh_count_and_not_a_ply(tmp_path):
    path = tmp_path / "odd.ply"
    _hand_written(path, 3, 1, drop="f_rest_8")  # 8 rest coefficients: not 3 * (K - 1)
    with pytest.raises(BundleError, match="odd.ply"):
        read_ply(path)
    junk = tmp_path / "junk.ply"
    junk.write_text("hello")
    with pytest.raises(BundleError, match="junk.ply"):
        read_ply(junk)
