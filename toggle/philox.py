"""The Monte Carlo's random draws: Philox4x32-10, counter-based, in numpy and in C.

A counter-based generator (Salmon, Moraes, Dror, Shaw, "Parallel random numbers: as easy
as 1, 2, 3", SC 2011) turns a counter and a key into random bits with no state between
calls, so the draws of sample i depend on (seed, i) alone: the compiled kernel
(:mod:`toggle.mc_kernel`) draws them where it uses them, any chunk or thread split gives
the same numbers, and this numpy implementation (vectorised on uint64, the fallback without
a C compiler) gives bit for bit the same uniforms. Philox4x32-10 is Random123's reference
generator (also cuRAND's Philox and TensorFlow's default); numpy's ``Philox`` is its 4x64
sibling, whose 64x64-bit products do not vectorise (AVX2/AVX-512 multiply 32x32 into 64
bits). Both implementations are checked against Random123's known-answer vectors; why this
generator and how it is tested: docs/tolerance.md.

Layout: the draws of sample i, half ``stream`` (0 lower, 1 upper), dimensions 2b and 2b+1
come from the block of counter (i mod 2^32, i div 2^32, b, stream) under the key of the
seed (two words from :class:`numpy.random.SeedSequence`). The block's words (w0, w1) and
(w2, w3) make two 53-bit integers m_a, m_b; a normal pair is Box-Muller's
sqrt(-2 ln u1) (cos, sin)(2 pi u2) with u1 = (m_a + 1) 2^-53 in (0, 1], u2 = m_b 2^-53; a
uniform pair over [-1, 1) is m 2^-52 - 1, exact.
"""

from __future__ import annotations

import numpy as np

from toggle.params import DIMENSIONS

#: Philox4x32's multipliers and Weyl key increments (Random123).
M0, M1 = 0xD2511F53, 0xCD9E8D57
W0, W1 = 0x9E3779B9, 0xBB67AE85
ROUNDS = 10
#: Blocks per sampled half: each gives two draws.
BLOCKS = (len(DIMENSIONS) + 1) // 2
_MASK = np.uint64(0xFFFFFFFF)

Key = tuple[int, int]

#: The same generator in C (included by the kernel's driver; uses N_DIMS).
C_SOURCE = rf"""
#include <stdint.h>

/* Philox4x32-10 (Random123): counter c, key (k0, k1), in place. */
static inline __attribute__((always_inline)) void philox4x32_10(uint32_t c[4], uint32_t k0,
                                                                uint32_t k1)
{{
#pragma GCC unroll {ROUNDS}
    for (int r = 0; r < {ROUNDS}; r++) {{
        const uint64_t p0 = (uint64_t)0x{M0:08X}u * c[0];
        const uint64_t p1 = (uint64_t)0x{M1:08X}u * c[2];
        const uint32_t n0 = (uint32_t)(p1 >> 32) ^ c[1] ^ k0;
        const uint32_t n2 = (uint32_t)(p0 >> 32) ^ c[3] ^ k1;
        c[0] = n0;
        c[1] = (uint32_t)p1;
        c[2] = n2;
        c[3] = (uint32_t)p0;
        k0 += 0x{W0:08X}u;
        k1 += 0x{W1:08X}u;
    }}
}}

/* The standard draws of sample i of a stream: normal (Box-Muller) or uniform on [-1, 1). */
static inline __attribute__((always_inline)) void toggle_draws_at(
    uint64_t i, uint32_t k0, uint32_t k1, uint32_t stream, int normal, double draw[N_DIMS])
{{
#pragma GCC unroll {BLOCKS}
    for (int b = 0; b < {BLOCKS}; b++) {{
        uint32_t c[4] = {{(uint32_t)i, (uint32_t)(i >> 32), (uint32_t)b, stream}};
        philox4x32_10(c, k0, k1);
        const double ma = (double)(((uint64_t)(c[0] >> 5) << 26) | (c[1] >> 6));
        const double mb = (double)(((uint64_t)(c[2] >> 5) << 26) | (c[3] >> 6));
        double d0, d1;
        if (normal) {{
            const double r = sqrt(-2.0 * log((ma + 1.0) * 0x1p-53));
            const double t = 0x1.921fb54442d18p+2 * (mb * 0x1p-53);  /* 2 pi u2 */
            d0 = r * cos(t);
            d1 = r * sin(t);
        }} else {{
            d0 = ma * 0x1p-52 - 1.0;
            d1 = mb * 0x1p-52 - 1.0;
        }}
        draw[2 * b] = d0;
        if (2 * b + 1 < N_DIMS)
            draw[2 * b + 1] = d1;
    }}
}}
"""


def key(seed: int | None) -> Key:
    """The generator's key for ``seed`` (None: fresh entropy from the system)."""
    words = np.random.SeedSequence(seed).generate_state(2, np.uint32)
    return int(words[0]), int(words[1])


def philox4x32(counter: tuple, k: Key) -> list[np.ndarray]:
    """Philox4x32-10 of counters (four arrays or ints of 32-bit words) under key ``k``:
    the four output words, uint64 arrays holding 32-bit values."""
    c = [np.asarray(w, dtype=np.uint64) for w in counter]
    k0, k1 = (np.uint64(w) for w in k)
    for _ in range(ROUNDS):
        p0, p1 = c[0] * np.uint64(M0), c[2] * np.uint64(M1)
        c = [(p1 >> np.uint64(32)) ^ c[1] ^ k0, p1 & _MASK,
             (p0 >> np.uint64(32)) ^ c[3] ^ k1, p0 & _MASK]
        k0, k1 = (k0 + np.uint64(W0)) & _MASK, (k1 + np.uint64(W1)) & _MASK
    return c


def draws(k: Key, start: int, n: int, stream: int, distribution: str) -> np.ndarray:
    """The standard draws (dimensions x n) of samples start .. start + n - 1 of ``stream``:
    ``"normal"`` or ``"uniform"`` on [-1, 1), as the C kernel draws them."""
    i = np.arange(start, start + n, dtype=np.uint64)
    out = np.empty((2 * BLOCKS, n))
    for b in range(BLOCKS):
        w = philox4x32((i & _MASK, i >> np.uint64(32), b, stream), k)
        ma, mb = (((hi >> np.uint64(5)) << np.uint64(26) | lo >> np.uint64(6)).astype(np.float64)
                  for hi, lo in ((w[0], w[1]), (w[2], w[3])))
        if distribution == "normal":
            r = np.sqrt(-2.0 * np.log((ma + 1.0) * 2.0**-53))
            t = (2.0 * np.pi) * (mb * 2.0**-53)
            out[2 * b], out[2 * b + 1] = r * np.cos(t), r * np.sin(t)
        else:
            out[2 * b], out[2 * b + 1] = ma * 2.0**-52 - 1.0, mb * 2.0**-52 - 1.0
    return out[:len(DIMENSIONS)]
