"""expf that vectorises and equals the scalar one bit for bit, for the exact composite.

numba's `np.exp` on float32 calls glibc's `expf`, which LLVM cannot vectorise (no vector math
library here). `expf_glibc` replays glibc's algorithm (sysdeps/ieee754/flt-32/e_expf.c, the
FMA build x86-64 selects: 2^(k/32) from a 32-entry table times a cubic in double precision,
rounded to float once) in plain arithmetic, so a loop calling it vectorises and still gives
the very same floats as `np.exp`. Checked against `np.exp` on every float32 in [-4.5, 0]
(the exact composite's domain: s <= S_MAX) and on samples elsewhere
(tests/test_splats_expf.py). Valid for |x| < 88 (no overflow or underflow handling), finite x.
It replays glibc >= 2.28 on x86-64 with FMA (this project's machines); under another libm,
np.exp may differ from it in the last bit, and the exact env frames from `StaticScene.render`
by that much (test_splats_expf and test_splats_frame would show it).
"""

from __future__ import annotations

from decimal import Decimal, getcontext

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

N = 32  # table entries (EXP2F_TABLE_BITS = 5)


def _table() -> np.ndarray:
    """glibc's __exp2f_data.tab: bits of 2^(i/N) (correctly rounded) minus i << 47."""
    getcontext().prec = 50
    ln2 = Decimal(2).ln()
    return np.array([int(np.float64(float((Decimal(i) / N * ln2).exp())).view(np.uint64))
                     - (i << 47) for i in range(N)], np.uint64)


TAB = _table()  # [N] uint64
INVLN2N = float.fromhex("0x1.71547652b82fep+0") * N
C0 = float.fromhex("0x1.c6af84b912394p-5") / N / N / N
C1 = float.fromhex("0x1.ebfce50fac4f3p-3") / N / N
C2 = float.fromhex("0x1.62e42ff0c52d6p-1") / N
SHIFT = float.fromhex("0x1.8p+52")


@intrinsic
def fma64(typingctx, a, b, c):
    """a * b + c rounded once (llvm.fma.f64)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, sig, args):
        return builder.fma(*args)

    return sig, codegen


def _bitcast(src, dst, doc: str):
    """An intrinsic that reinterprets a value of numba type src as dst (same width)."""
    @intrinsic
    def cast(typingctx, x):
        def codegen(context, builder, sig, args):
            return builder.bitcast(args[0], context.get_value_type(dst))

        return dst(src), codegen

    cast.__doc__ = doc
    return cast


f64_bits = _bitcast(types.float64, types.uint64, "The bits of a float64 as uint64.")
bits_f64 = _bitcast(types.uint64, types.float64, "The float64 whose bits are the uint64 u.")
bits_f32 = _bitcast(types.int32, types.float32, "The float32 whose bits are the int32 u.")


@njit(cache=True, inline="always")
def expf_glibc(x):
    """exp(x) of a float32, bit-identical to glibc's expf (|x| < 88)."""
    xd = np.float64(x)
    kd = fma64(INVLN2N, xd, SHIFT)  # round(x N / ln 2) in the low bits of kd
    ki = f64_bits(kd)
    kd -= SHIFT
    r = fma64(INVLN2N, xd, -kd)  # in [-1/2, 1/2]
    s = bits_f64(TAB[ki % np.uint64(N)] + (ki << np.uint64(47)))
    z = fma64(C0, r, C1)
    y = fma64(C2, r, 1.0)
    y = fma64(z, r * r, y)
    return np.float32(y * s)


F32 = np.float32
LOG2E_F = F32(1.44269504088896341)
LN2_HI_F, LN2_LO_F = F32(0.693359375), F32(-2.12194440e-4)
P0, P1, P2, P3, P4, P5 = (F32(1.9875691500e-4), F32(1.3981999507e-3), F32(8.3334519073e-3),
                          F32(4.1665795894e-2), F32(1.6666665459e-1), F32(5.0000001201e-1))


@njit(cache=True, inline="always")
def expf_lanes(x):
    """exp(x) of a float32 in float32 lanes (Cephes' expf: 2^k times a degree-7 polynomial of
    the reduced argument; within 3 ulp of glibc's expf on [-87, 0]). For loops whose results
    need not equal np.exp bit for bit (the composite's backward): 8 lanes per AVX2 register,
    no table, no double precision. x below -87 is clamped (the result is then ~1e-38)."""
    x = max(x, F32(-87.0))
    k = np.floor(x * LOG2E_F + F32(0.5))
    r = x - k * LN2_HI_F
    r = r - k * LN2_LO_F
    p = P0 * r + P1
    p = p * r + P2
    p = p * r + P3
    p = p * r + P4
    p = p * r + P5
    p = p * r * r + r + F32(1.0)
    return p * bits_f32((np.int32(k) + np.int32(127)) << np.int32(23))
