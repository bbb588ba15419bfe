"""Reconstruction schedule: coarse-to-fine levels and the held-out convergence stop (toy clip)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from recon_toy import make_toy_clip
from vid2sim.factory.recon import config as C
from vid2sim.factory.recon.data import downscale_view, load_views
from vid2sim.factory.recon.depth_prior import DepthPrior
from vid2sim.factory.recon.trainer import make_level, prior_tensors, train
from vid2sim.factory.sfm.posed import PosedClip


def tiny_conf(**kw) -> C.ReconConfig:
    conf = C.preset("fast", **{"iterations": 40, "max_width": 40, "checkpoint_every": 100_000,
                               "max_init_points": 600, **kw})
    conf.densify = dataclasses.replace(conf.densify, start_iter=10, stop_iter=35, every=10,
                                       opacity_reset_every=1000, max_gaussians=2000)
    conf.loss = dataclasses.replace(conf.loss, geometry_from_iter=5)
    return conf


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return make_toy_clip(tmp_path_factory.mktemp("toy"), n_frames=17, width=48, height=36, n_points=1500)


def test_downscaled_view_and_prior_keep_the_geometry(toy):
    clip = PosedClip.load(toy)
    v = load_views(clip, 40)[0]
    half = downscale_view(v, 0.5)
    assert (half.width, half.height) == (20, 15) and half.mask.shape == (15, 20)
    # the same world ray hits the same relative image position: principal point and focal halve
    assert np.allclose(half.K[:2, :3], 0.5 * v.K[:2, :3], rtol=0.02)
    assert abs(float(half.image.mean()) - float(v.image.mean())) < 0.01  # area averaging
    depth = np.full((v.height, v.width), 3.0, np.float32)
    conf = np.ones_like(depth, bool)
    conf[:, : v.width // 2] = False
    pt = prior_tensors(DepthPrior(depth, conf), half, window=5)
    assert tuple(pt.depth.shape) == (15, 20)
    assert not bool(pt.conf[:, :9].any()) and bool(pt.conf[:, 11:].all())
    # a fronto-parallel plane: the prior normals face the camera (-z)
    assert float(pt.normal[pt.normal_ok][:, 2].mean()) < -0.99


def test_coarse_levels_then_full_resolution_and_holdout_stop(toy, tmp_path):
    clip = PosedClip.load(toy)
    views = load_views(clip, 40)
    train_views = [v for v in views if v.split == "train"]
    coarse = make_level(tiny_conf(), train_views, {}, 0.5)
    full = make_level(tiny_conf(), train_views, {}, 1.0)
    i = train_views[0].index
    assert coarse.cams[i].width * 2 == full.cams[i].width == 40
    assert tuple(coarse.gts[i][0].shape) == (15, 20, 3)
    # min_delta 50 %: no held-out check after densification stops (iteration 35) improves
    # that much, so training stops at the second such check (40), long before 400
    conf = tiny_conf(iterations=400, coarse_iterations=20, coarse_scale=0.5, holdout_every=5,
                     holdout_patience=2, holdout_min_delta=0.5)
    _, s = train(conf, clip, views, {}, tmp_path, key="k", log_every=5)
    checks = [e for e in s["log"] if "holdout_l1" in e]
    assert [e["iter"] for e in checks][:2] == [5, 10]
    assert s["iterations"] == 40 and any(e.get("stopped") for e in s["log"])
    assert checks[-1]["holdout_l1"] < checks[0]["holdout_l1"]  # it did learn the held-out frames
    # without a held-out check the same config runs every iteration
    _, s2 = train(dataclasses.replace(conf, iterations=45, holdout_every=0), clip, views, {}, tmp_path / "b",
                  key="k", log_every=5)
    assert s2["iterations"] == 45
