"""expf_glibc (the vectorisable expf of the exact env composite) against numba's np.exp."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from vid2sim.splats.cpu._expf import expf_glibc, expf_lanes

TOP = int(np.float32(4.5).view(np.uint32)) + 1  # bit patterns of the float32 in [0, 4.5]


@njit(cache=True)
def _mismatches(xs):
    """Count of x in xs [N] float32 where expf_glibc(x) != np.exp(x) (bitwise)."""
    bad = 0
    for i in range(xs.shape[0]):
        if np.exp(xs[i]) != expf_glibc(xs[i]):
            bad += 1
    return bad


def test_expf_equals_np_exp_on_the_composite_domain_sample():
    """Every 61st float32 in [-4.5, 0] (the composite's exp(-s), s <= S_MAX) and random
    values in [-87, 87]: the same bits as np.exp (glibc's expf)."""
    xs = -np.arange(0, TOP, 61, dtype=np.uint32).view(np.float32)
    assert xs.size > 10_000_000
    assert _mismatches(xs) == 0
    rng = np.random.default_rng(0)
    assert _mismatches(rng.uniform(-87.0, 87.0, 1_000_000).astype(np.float32)) == 0
    edge = np.array([0.0, -0.0, -4.5, -1e-30, -1e-7, 1e-7, 1.0, -1.0], np.float32)
    assert _mismatches(edge) == 0


@pytest.mark.slow
def test_expf_equals_np_exp_exhaustive():
    """Every float32 in [-4.5, 0] (1.08e9 values; ~40 s)."""
    step = 1 << 26
    bad = 0
    for lo in range(0, TOP, step):
        bad += _mismatches(-np.arange(lo, min(lo + step, TOP), dtype=np.uint32).view(np.float32))
    assert bad == 0


@njit(cache=True)
def _lanes(xs, out):
    for i in range(xs.shape[0]):
        out[i] = expf_lanes(xs[i])


def test_expf_lanes_within_3_ulp_of_np_exp():
    """expf_lanes (the composite backward's exp) against np.exp on every 97th float32 in
    [-87, 0]; far below that it clamps to a tiny positive value, never inf or nan."""
    xs = -np.arange(0, int(np.float32(87.0).view(np.uint32)) + 1, 97, dtype=np.uint32).view(np.float32)
    out = np.empty_like(xs)
    _lanes(xs, out)
    ulp = np.abs(out.view(np.int32).astype(np.int64) - np.exp(xs).view(np.int32).astype(np.int64))
    assert xs.size > 10_000_000 and ulp.max() <= 3
    far = np.array([-88.0, -1e3, -1e30, -np.inf], np.float32)
    out = np.empty_like(far)
    _lanes(far, out)
    assert np.all(np.isfinite(out)) and np.all(out >= 0.0) and np.all(out < 1e-37)
