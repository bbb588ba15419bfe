"""The CPU thread pools a computation may use: torch's, numba's and OpenMP's, set together.

`set_thread_pools(n)` sets them for the rest of the process (a factory task bounds itself to the CPUs
Ray gave it); `thread_pools(n)` bounds them while inside a `with` block and restores them after (a
training run bounds itself and leaves its caller as it was). numba's count is per calling thread and
never above the pool it was started with (`NUMBA_NUM_THREADS`). This module sits in the base layer,
so the factory and the training can both use it.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

import numba
import torch


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def set_thread_pools(threads: int) -> None:
    """Set torch's, numba's (this thread's) and OpenMP's thread counts to `threads` (>= 1)."""
    torch.set_num_threads(threads)
    try:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except ValueError:  # numba's pool not launchable here; torch's bound still holds
        pass
    os.environ["OMP_NUM_THREADS"] = str(threads)


@contextmanager
def thread_pools(threads: int) -> Iterator[None]:
    """Bound torch's, numba's and OpenMP's thread counts to `threads` while inside, then restore
    them; 0 leaves them as they are."""
    if threads <= 0:
        yield
        return
    before = torch.get_num_threads(), numba.get_num_threads(), os.environ.get("OMP_NUM_THREADS")
    set_thread_pools(threads)
    try:
        yield
    finally:
        numba.set_num_threads(before[1])  # numba's OpenMP layer may set torch's pool too: torch's last
        torch.set_num_threads(before[0])
        if before[2] is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = before[2]


@contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """Bound torch's intra-op pool alone to `threads` while inside (numba's stays as it is), then
    restore it: a loop whose heavy work is numba kernels and whose torch ops are many small
    images runs those on one thread, where waking a second costs more than it saves."""
    before = torch.get_num_threads()
    torch.set_num_threads(max(1, threads))
    try:
        yield
    finally:
        torch.set_num_threads(before)
