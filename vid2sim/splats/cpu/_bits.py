"""Bit intrinsics for the composite kernels' per-row masks of stopped pixels."""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic


@intrinsic
def popc64(typingctx, x):
    """Number of set bits of a uint64."""
    if x != types.uint64:
        return None
    sig = types.uint64(types.uint64)

    def codegen(context, builder, sig, args):
        return builder.ctpop(args[0])

    return sig, codegen
