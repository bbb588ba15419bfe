"""The CPU threads a step may use: the CPUs Ray assigned to its task (else the clip's share)."""

from __future__ import annotations

import ray

from vid2sim.threads import set_thread_pools

_assigned = 1


def limit_threads(cpus: float) -> int:
    """Limit torch/numba/OpenMP threads to the task's CPUs; returns the count (>= 1)."""
    global _assigned
    n = cpus
    if ray.is_initialized():
        n = ray.get_runtime_context().get_assigned_resources().get("CPU", cpus)
    n = max(1, int(n or 1))
    set_thread_pools(n)
    _assigned = n
    return n


def assigned_threads() -> int:
    """The count the last `limit_threads` set in this process (1 before any)."""
    return _assigned
