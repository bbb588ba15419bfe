"""expf_glibc (the vectorisable expf of the exact env composite) against numba's np.exp."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from vid2sim.splats.cpu._expf import expf_glibc

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
