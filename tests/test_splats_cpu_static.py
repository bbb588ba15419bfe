"""StaticScene (forward-only env path) renders what `rasterize` renders."""

from __future__ import annotations

import pytest
import torch

from vid2sim.splats.cpu import StaticScene, StaticSceneConfig, rasterize
from vid2sim.splats.cpu.synthetic import robot_camera, street_scene
from vid2sim.splats.render import finish
from vid2sim.splats.types import RasterSettings


@pytest.fixture(scope="module")
def street():
    return street_scene(6000, length=30.0, seed=1)


@pytest.mark.parametrize("pose,degree,cov", [
    (dict(x=-10.0, yaw_deg=0.0), 0, None),
    (dict(x=0.0, yaw_deg=35.0), 3, None),
    (dict(x=5.0, y=-4.0, yaw_deg=80.0), 1, 0.01),  # facing a facade, big splats culled
])
def test_static_matches_rasterize(street, pose, degree, cov):
    cam = robot_camera(64, 36, **pose)
    st = RasterSettings(64, 36, active_sh_degree=degree, cov_cull_alpha=cov)
    scene = StaticScene(street)
    m = street
    ref = finish(rasterize(m.means, m.quats, m.log_scales, m.opacity_logits, m.sh, cam, st),
                 (0.2, 0.3, 0.4))
    out = scene.render(cam, st, background=(0.2, 0.3, 0.4))
    assert ref.alpha.mean() > 0.3
    for k in ("rgb", "alpha", "median_depth", "normal"):
        torch.testing.assert_close(getattr(out, k), getattr(ref, k), atol=2e-4, rtol=1e-4)
    torch.testing.assert_close(out.depth, ref.depth, atol=1e-3, rtol=1e-4)
    vis = ref.raw.radii > 0
    assert torch.equal(out.raw.radii > 0, vis)  # frustum culling drops no visible splat
    torch.testing.assert_close(out.raw.means2d[vis], ref.raw.means2d[vis], atol=1e-3, rtol=1e-5)
    assert out.raw.grad2d is None


def test_static_culls_cells_behind(street):
    """A camera at the street end looking outwards sees nothing and projects nothing."""
    scene = StaticScene(street)
    cam = robot_camera(64, 36, x=16.0, yaw_deg=0.0)
    out = scene.render(cam, RasterSettings(64, 36))
    assert float(out.alpha.max()) == 0.0 and int((out.raw.radii > 0).sum()) == 0


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1.0 / ((a - b) ** 2).mean().clamp_min(1e-20)))


def test_lod_radius_zero_is_exact(street):
    """With lod_pixel_radius=0 no node is merged: the LOD walk emits every visible splat."""
    cam = robot_camera(64, 36, x=-12.0, yaw_deg=10.0)
    st = RasterSettings(64, 36, active_sh_degree=1)
    ex = StaticScene(street).render(cam, st)
    lod = StaticScene(street, StaticSceneConfig(lod=True, lod_pixel_radius=0.0)).render(cam, st)
    for k in ("rgb", "alpha", "depth", "median_depth", "normal"):
        torch.testing.assert_close(getattr(lod, k), getattr(ex, k), atol=2e-4, rtol=1e-4)
    assert torch.equal(lod.raw.radii > 0, ex.raw.radii > 0)


def test_lod_merges_distant_splats_with_small_error():
    """LOD (opt-in, approximate) projects fewer Gaussians and stays close to the exact image."""
    street = street_scene(20000, length=60.0, seed=1)
    cam = robot_camera(128, 72, x=-29.0)
    st = RasterSettings(128, 72, active_sh_degree=0)
    ex = StaticScene(street).render(cam, st)
    scene = StaticScene(street, StaticSceneConfig(lod=True, lod_pixel_radius=0.5))
    out = scene.render(cam, st)
    assert scene.lod is not None and len(scene.lod.opacity) > 0
    # merged nodes have no model index (radii 0): most distant splats went into nodes
    assert int((out.raw.radii > 0).sum()) < 0.6 * int((ex.raw.radii > 0).sum())
    assert _psnr(out.rgb, ex.rgb) > 33.0
    assert float((out.alpha - ex.alpha).abs().mean()) < 0.02


def test_per_splat_outputs_off_and_big_tiles(street):
    cam = robot_camera(64, 36, x=-10.0)
    full = StaticScene(street).render(cam, RasterSettings(64, 36))
    lean = StaticScene(street, StaticSceneConfig(per_splat_outputs=False)).render(
        cam, RasterSettings(64, 36, tile_size=128))  # kernels cap the tile at 32 px (MAX_TILE)
    assert lean.raw.radii.shape == (0,) and lean.raw.means2d.shape == (0, 2)
    torch.testing.assert_close(lean.rgb, full.rgb, atol=2e-4, rtol=1e-4)
