"""Dynamic work sharing for the parallel kernels: an atomic counter that the workers of a
`prange(n_workers)` loop draw work items (tiles, chunks of splats) from.

Static splits (numba's default for prange) leave a thread idle whenever its share is
cheaper, or when another process slows the core it runs on (the usual case on a shared
2-core box); drawing items one at a time keeps every worker busy until the list is done.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

CHUNK = 2048  # splats per work item in the per-splat kernels


@intrinsic
def fetch_add(typingctx, arr, val):
    """Atomically add val to arr[0] (int64 [1]) and return the previous value."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64):
        return None
    sig = types.int64(arr, types.int64)

    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, sig.args[0], ary,
                                       [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, args[1], "seq_cst")

    return sig, codegen


@njit(cache=True)
def new_counter():
    """A zeroed int64 [1] counter for fetch_add."""
    return np.zeros(1, np.int64)


@njit(cache=True)
def n_chunks(n, chunk):
    """Number of work items of `chunk` elements covering n elements."""
    return (n + chunk - 1) // chunk
