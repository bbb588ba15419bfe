"""Augmentation: off by default, exposure, fog by depth, depth-aware rain and snow, seeding."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vid2sim.envs.augment import AugmentConfig, Augmenter, fog, particles

H, W = 72, 128
GREY = np.full((H, W, 3), 100, np.uint8)


def _plain(**kw) -> AugmentConfig:
    """Enabled config with every effect off unless given."""
    base = dict(enabled=True, exposure_ev=(0.0, 0.0), white_balance=(1.0, 1.0), tints=("day",),
                fog_prob=0.0, rain_prob=0.0, snow_prob=0.0)
    base.update(kw)
    return AugmentConfig(**base)


def test_disabled_by_default_is_identity() -> None:
    aug = Augmenter()
    assert not aug.config.enabled
    assert aug.reset(np.random.default_rng(0)) is None
    out = aug.apply(GREY, np.full((H, W), 5.0, np.float32))
    assert np.array_equal(out, GREY)


def test_exposure_one_stop_doubles() -> None:
    aug = Augmenter(_plain(exposure_ev=(1.0, 1.0)))
    aug.reset(np.random.default_rng(0))
    out = aug.apply(GREY, np.full((H, W), 5.0, np.float32))
    assert out.dtype == np.uint8 and out.shape == GREY.shape
    assert (out == 200).all()


def test_fog_grows_with_depth_and_covers_the_sky() -> None:
    depth = np.tile(np.linspace(0.5, 60.0, W, dtype=np.float32), (H, 1))
    depth[:10] = np.inf  # sky
    depth[10:15] = 0.0  # uncovered splat pixels
    img = np.zeros((H, W, 3), np.float32)
    out = fog(img, np.where(depth > 0, depth, np.inf), 0.1, np.array([200.0, 200.0, 200.0]))
    row = out[40, :, 0]
    assert (np.diff(row) > 0).all()  # farther -> foggier
    assert row[0] < 10 and row[-1] > 199
    assert np.allclose(out[:15], 200.0)
    aug = Augmenter(_plain(fog_prob=1.0, fog_density=(0.1, 0.1)))
    aug.reset(np.random.default_rng(0))
    out8 = aug.apply(np.zeros((H, W, 3), np.uint8), depth)
    assert out8[40, 0, 0] < out8[40, -1, 0]


@pytest.mark.parametrize("kind", ["rain", "snow"])
def test_particles_hide_behind_nearer_geometry(kind: str) -> None:
    img = np.zeros((H, W, 3), np.float32)
    near = np.full((H, W), 0.2, np.float32)  # a wall nearer than every particle (>= 0.3 m)
    far = np.full((H, W), 50.0, np.float32)
    out_near = particles(img, near, np.random.default_rng(0), 500, kind, 0.1, (0.3, 10.0))
    out_far = particles(img, far, np.random.default_rng(0), 500, kind, 0.1, (0.3, 10.0))
    assert (out_near == 0).all()
    assert (out_far > 0).any(-1).mean() > 0.02
    split = far.copy()
    split[:, : W // 2] = 0.2  # left half: near wall; right half: open street
    out_split = particles(img, split, np.random.default_rng(0), 500, kind, 0.1, (0.3, 10.0))
    assert (out_split[:, : W // 2] == 0).all() and (out_split[:, W // 2:] > 0).any()


def test_episode_randomisation_is_seeded_and_in_range() -> None:
    cfg = dataclasses.replace(AugmentConfig(enabled=True), fog_prob=0.5, rain_prob=0.3, snow_prob=0.3)
    depth = np.full((H, W), 8.0, np.float32)
    a, b = Augmenter(cfg), Augmenter(cfg)
    pa, pb = a.reset(np.random.default_rng(7)), b.reset(np.random.default_rng(7))
    assert np.array_equal(pa.gain, pb.gain) and (pa.weather, pa.fog_density) == (pb.weather, pb.fog_density)
    assert np.array_equal(a.apply(GREY, depth), b.apply(GREY, depth))  # same per-frame particles
    seen = {"weather": set(), "tint": set(), "fog": set()}
    for seed in range(60):
        p = a.reset(np.random.default_rng(seed))
        seen["weather"].add(p.weather)
        seen["tint"].add(p.tint)
        seen["fog"].add(p.fog_density > 0)
        assert (p.gain > 0.1).all() and (p.gain < 3.5).all()
        assert p.fog_density == 0 or 0.03 <= p.fog_density <= 0.25
    assert seen["weather"] == {"clear", "rain", "snow"}
    assert seen["tint"] == {"day", "golden", "dusk", "night"} and seen["fog"] == {True, False}


def test_apply_kernel_agrees_with_the_numpy_reference() -> None:
    """The one-pass numba tone (exposure, tint, fog) + particles equals the plain numpy path
    up to float rounding: at most one level, on few pixels."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    depth = rng.uniform(0.2, 40.0, size=(H, W)).astype(np.float32)
    depth[:10] = np.inf  # sky
    depth[10:12] = 0.0  # empty
    conf = AugmentConfig(enabled=True, fog_prob=0.5, rain_prob=0.3, snow_prob=0.3)
    seen, diff = set(), []
    for seed in range(24):
        a, b = Augmenter(conf), Augmenter(conf)
        pa, _ = a.reset(np.random.default_rng(seed)), b.reset(np.random.default_rng(seed))
        seen.add((pa.weather, pa.fog_density > 0))
        out, ref = a.apply(img, depth), b.apply_reference(img, depth)
        d = np.abs(out.astype(int) - ref.astype(int))
        assert d.max() <= 1
        diff.append((d > 0).mean())
    assert len(seen) >= 5  # clear / rain / snow, with and without fog
    assert np.mean(diff) < 0.01
