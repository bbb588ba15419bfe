"""Depth priors: plane-sweep geometry and accuracy on the ray-cast toy clip; DA-V2 errors."""

from __future__ import annotations


import numpy as np
import pytest

from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.recon.config import DepthPriorConfig
from vid2sim.factory.recon.data import load_views
from vid2sim.factory.recon.depth_prior import (DepthPrior, align_disparity, estimate_priors, filter_consistent,
                                               mean_of_top_two, mvs_priors, plane_homography)
from vid2sim.factory.recon.evaluate import load_gt_depths
from recon_toy import make_toy_clip, toy_poses
from vid2sim.factory.runtime.stage_cache import StageError


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return make_toy_clip(tmp_path_factory.mktemp("toy"), n_frames=17, width=64, height=48)


def test_plane_homography_maps_plane_points():
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    a, b = toy_poses(3)[0], toy_poses(3)[2]
    T = np.linalg.inv(b) @ a  # ref camera -> neighbour camera
    X = np.array([0.7, -0.4, 4.0])  # on the plane z_ref = 4
    H = plane_homography(K, K, T, 4.0)
    p_ref = K @ X
    p_ref = p_ref[:2] / p_ref[2] - 0.5  # OpenCV integer-centre coords
    Xn = T[:3, :3] @ X + T[:3, 3]
    p_nb = K @ Xn
    p_nb = p_nb[:2] / p_nb[2] - 0.5
    q = H @ np.array([*p_ref, 1.0])
    assert np.allclose(q[:2] / q[2], p_nb, atol=1e-9)


def test_plane_sweep_depth_is_accurate_where_confident(toy):
    clip = PosedClip.load(toy)
    views = load_views(clip, 64)
    priors = estimate_priors(DepthPriorConfig(kind="mvs", num_planes=64), views, clip.points_xyz)
    assert set(priors) == {v.index for v in views if v.split == "train"}
    gt = load_gt_depths(toy.parent / "gt_depth", views)
    rel, cover = [], []
    for idx, pr in priors.items():
        ok = pr.confidence
        cover.append(ok.mean())
        if ok.any():
            rel.append(np.median(np.abs(pr.depth[ok] - gt[idx][ok]) / gt[idx][ok]))
    assert np.mean(cover) > 0.3
    assert np.median(rel) < 0.08  # fronto-parallel windows on slanted walls at 64 px


@pytest.mark.parametrize("count", [1, 2, 3, 4, 6])
def test_mean_of_top_two_equals_sorting_the_stack(count):
    rng = np.random.default_rng(count)
    scores = [rng.uniform(-1, 1, (9, 11)).astype(np.float32) for _ in range(count)]
    scores[0][0, :4] = -1.0  # ties, as windows the neighbours do not see
    if count > 1:
        scores[1][0, :4] = -1.0
    stack = np.sort(np.stack(scores), axis=0)
    expected = stack[-min(2, count):].mean(0)
    got = mean_of_top_two(scores)
    assert got.dtype == np.float32 and np.array_equal(got, expected)


def test_plane_sweep_priors_do_not_depend_on_the_thread_count(toy):
    clip = PosedClip.load(toy)
    views = load_views(clip, 64)
    conf = DepthPriorConfig(kind="mvs", num_planes=24)
    one = mvs_priors(views, clip.points_xyz, conf, threads=1)
    two = mvs_priors(views, clip.points_xyz, conf, threads=2)
    assert list(one) == list(two) and any(p.confidence.any() for p in one.values())
    for idx in one:
        assert np.array_equal(one[idx].depth, two[idx].depth)
        assert np.array_equal(one[idx].confidence, two[idx].confidence)


def test_consistency_filter_keeps_agreeing_depth_and_drops_wrong_depth(toy):
    """Exact depth in every view is consistent; a patch placed 1.5x too far in one view is not."""
    clip = PosedClip.load(toy)
    views = [v for v in load_views(clip, 64) if v.split == "train"]
    gt = load_gt_depths(toy.parent / "gt_depth", views)
    priors = {v.index: DepthPrior(gt[v.index].astype(np.float32), gt[v.index] > 0) for v in views}
    ref = views[len(views) // 2].index
    wrong = np.zeros_like(priors[ref].confidence)
    wrong[10:30, 20:44] = True
    priors[ref] = DepthPrior(np.where(wrong, 1.5, 1.0).astype(np.float32) * priors[ref].depth, priors[ref].confidence)
    out = filter_consistent(views, priors, DepthPriorConfig())
    kept = out[ref].confidence
    assert kept[wrong].mean() < 0.05
    assert kept[~wrong & (gt[ref] > 0)].mean() > 0.8
    assert np.all(out[ref].depth[~kept] == 0)
    others = [v.index for v in views if v.index != ref]
    assert np.mean([out[i].confidence[gt[i] > 0].mean() for i in others]) > 0.8
    same = filter_consistent(views, priors, DepthPriorConfig(consistency_rel=0.0))
    assert same[ref] is priors[ref]
    with pytest.raises(StageError, match="bad_prior_config"):
        filter_consistent(views, priors, DepthPriorConfig(consistency_views=1, min_consistent=3))


def test_consistency_filter_lowers_plane_sweep_outliers(toy):
    clip = PosedClip.load(toy)
    views = load_views(clip, 64)
    gt = load_gt_depths(toy.parent / "gt_depth", views)

    def outliers(conf: DepthPriorConfig) -> tuple[float, int]:
        priors = estimate_priors(conf, views, clip.points_xyz)
        rel = np.concatenate([np.abs(p.depth[p.confidence] / gt[i][p.confidence] - 1) for i, p in priors.items()])
        return float(np.mean(rel > 0.2)), rel.size

    raw, n_raw = outliers(DepthPriorConfig(kind="mvs", num_planes=64, consistency_rel=0.0))
    filtered, n_filtered = outliers(DepthPriorConfig(kind="mvs", num_planes=64))
    assert filtered < 0.5 * raw
    assert n_filtered > 0.3 * n_raw


def test_none_prior_is_empty(toy):
    clip = PosedClip.load(toy)
    assert estimate_priors(DepthPriorConfig(kind="none"), load_views(clip, 32), clip.points_xyz) == {}


def test_depth_anything_needs_a_local_checkpoint(toy, tmp_path):
    clip = PosedClip.load(toy)
    views = load_views(clip, 32)
    for ckpt in (None, str(tmp_path / "absent")):
        with pytest.raises(StageError) as e:
            estimate_priors(DepthPriorConfig(kind="depth_anything", checkpoint=ckpt), views, clip.points_xyz)
        assert e.value.reason == "depth_prior_checkpoint_missing"
    with pytest.raises(StageError, match="unknown_depth_prior"):
        estimate_priors(DepthPriorConfig(kind="zoe"), views, clip.points_xyz)


def test_align_disparity_recovers_metric_depth():
    rng = np.random.default_rng(0)
    depth = rng.uniform(2, 20, (30, 40))
    disp = 3.0 * (1.0 / depth) - 0.05  # affine relative disparity
    uv = np.stack([rng.integers(0, 40, 50), rng.integers(0, 30, 50)], 1).astype(float)
    z = depth[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    out = align_disparity(disp, uv, z)
    assert np.allclose(out, depth, rtol=1e-6)
    assert align_disparity(disp, uv[:5], z[:5]) is None
