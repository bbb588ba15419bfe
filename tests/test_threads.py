"""The thread-pool bounds shared by the factory's tasks and the training runs (`vid2sim.threads`)."""

from __future__ import annotations

import os

import numba
import torch

from vid2sim.threads import set_thread_pools, thread_pools


def test_thread_pools_bound_inside_and_restore_all_three_after(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    original = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(2)  # both pools at two threads, as a 2-core machine starts them
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    before = torch.get_num_threads(), numba.get_num_threads()
    try:
        with thread_pools(1):
            assert (torch.get_num_threads(), numba.get_num_threads(), os.environ["OMP_NUM_THREADS"]) == (1, 1, "1")
        assert (torch.get_num_threads(), numba.get_num_threads()) == before
        assert "OMP_NUM_THREADS" not in os.environ
    finally:
        numba.set_num_threads(original[1])
        torch.set_num_threads(original[0])


def test_thread_pools_restore_after_an_error_and_zero_leaves_them(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    before = torch.get_num_threads()
    try:
        with thread_pools(1):
            raise KeyError("inside")
    except KeyError:
        pass
    assert torch.get_num_threads() == before and os.environ["OMP_NUM_THREADS"] == "7"
    with thread_pools(0):
        assert torch.get_num_threads() == before and os.environ["OMP_NUM_THREADS"] == "7"


def test_set_thread_pools_caps_numba_at_its_launched_pool(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    before = torch.get_num_threads(), numba.get_num_threads()
    try:
        set_thread_pools(numba.config.NUMBA_NUM_THREADS + 3)
        assert torch.get_num_threads() == numba.config.NUMBA_NUM_THREADS + 3
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    finally:
        numba.set_num_threads(before[1])
        torch.set_num_threads(before[0])
