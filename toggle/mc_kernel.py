"""Compiled Monte Carlo kernel: the output position of a half for a whole array of samples.

The equations are not written here: CasADi generates C for
:func:`toggle.kinematics.output_position` (the one source of the clamp's equations) and
a small C driver loops over the samples, drawing each sample's dimensions with
:mod:`toggle.philox`'s generator (its C text, the same numbers as its numpy), forming each
sampled half as ``nominal + scale * draw`` (the same operations, in the same order, as numpy
does) and calling the generated function inlined. gcc vectorises that loop with glibc's vector
math library (libmvec: acos, asin, sin, cos, log four or eight at a time, within 4 ulp), which
is what makes the kernel several times faster than numpy's ufunc chain; where libmvec
is missing a scalar build is used. The library is compiled once per machine and cached
(:mod:`toggle.c_library`) under a key of its own C text, so editing the kinematics
compiles it again. The driver counts the samples whose output is not finite; the caller
re-evaluates those chunks with numpy, which raises the same
:class:`~toggle.kinematics.AssemblyError` or clips the same rounding-level excursions as
before. Where no C compiler works, :func:`load` returns None after a one-line warning and
the caller stays with numpy (same results, slower).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import warnings
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import numpy as np

from toggle import philox
from toggle.c_library import Sources, casadi_c, shared_library
from toggle.kinematics import output_position
from toggle.mc_summary import QUANTILES
from toggle.params import DIMENSIONS

_DRIVER = r"""
#include <math.h>
#include "kinematics.c"
#include "philox.c"

/* glibc's vector variants (libmvec) of the functions the generated code and the draws call. */
#ifdef TOGGLE_LIBMVEC
__attribute__((simd("notinbranch"), const)) double acos(double);
__attribute__((simd("notinbranch"), const)) double asin(double);
__attribute__((simd("notinbranch"), const)) double sin(double);
__attribute__((simd("notinbranch"), const)) double cos(double);
__attribute__((simd("notinbranch"), const)) double log(double);
#endif

/* Output position of one sampled half at x: dimension k is nominal[k] + scale[k] * draw[k]. */
static inline double half_output(double x, const double nom[N_DIMS], const double sc[N_DIMS],
                                 const double draw[N_DIMS])
{
    double p[N_DIMS];
    for (int k = 0; k < N_DIMS; k++)
        p[k] = nom[k] + sc[k] * draw[k];
    const casadi_real *arg[2] = {&x, p};
    casadi_real L;
    casadi_real *res[1] = {&L};
    casadi_f0(arg, res, 0, 0, 0);
    return L;
}

/* Output positions of n sampled halves at x: the draws of sample i are draws[k * n + i].
   Returns how many outputs are not finite (NaN or infinite). */
long toggle_mc_half(long n, double x, const double *restrict nominal,
                    const double *restrict scale, const double *restrict draws,
                    double *restrict out)
{
    double nom[N_DIMS], sc[N_DIMS];
    for (int k = 0; k < N_DIMS; k++) {
        nom[k] = nominal[k];
        sc[k] = scale[k];
    }
    long bad = 0;
    for (long i = 0; i < n; i++) {
        double d[N_DIMS];
        for (int k = 0; k < N_DIMS; k++)
            d[k] = draws[k * n + i];
        out[i] = half_output(x, nom, sc, d);
        bad += !(out[i] - out[i] == 0.0);
    }
    return bad;
}

/* Samples are evaluated in tiles of a fixed count, so every sample takes the same
   (vectorised) path whatever the chunk it falls in: the same bits for any split. */
#define TILE 16

static inline __attribute__((always_inline)) long sampled(
    long start, long n, uint32_t k0, uint32_t k1, uint32_t stream, int normal, double x,
    const double nom[N_DIMS], const double sc[N_DIMS], double *restrict out)
{
    long bad = 0;
    for (long t = 0; t < n; t += TILE) {
        double L[TILE];
        for (int j = 0; j < TILE; j++) {
            double d[N_DIMS];
            toggle_draws_at((uint64_t)(start + t + j), k0, k1, stream, normal, d);
            L[j] = half_output(x, nom, sc, d);
        }
        const long m = n - t < TILE ? n - t : TILE;
        for (long j = 0; j < m; j++) {
            out[t + j] = L[j];
            bad += !(L[j] - L[j] == 0.0);
        }
    }
    return bad;
}

/* Output positions of samples start .. start + n - 1 of a stream (a half), their draws
   made here (philox.c): normal or uniform. Returns how many are not finite. */
long toggle_mc_sampled(long start, long n, uint32_t k0, uint32_t k1, uint32_t stream,
                       int normal, double x, const double *restrict nominal,
                       const double *restrict scale, double *restrict out)
{
    double nom[N_DIMS], sc[N_DIMS];
    for (int k = 0; k < N_DIMS; k++) {
        nom[k] = nominal[k];
        sc[k] = scale[k];
    }
    return normal ? sampled(start, n, k0, k1, stream, 1, x, nom, sc, out)
                  : sampled(start, n, k0, k1, stream, 0, x, nom, sc, out);
}

/* The summary of samples start .. start + n - 1 of a run, from both halves' outputs
   (toggle/mc_summary.py: the same operations as its numpy): the outputs v are the lower and
   upper errors L - nominal and the asymmetry L_upper - L_lower; per block of `block`
   samples (the run's, whatever the call) the sums of d = v - shift and of d * d, in sample
   order; per quantile window j of an output, the count of values below lo[j] and the values
   in [lo[j], hi[j]] (kept from base[j], at most cap[j]; filled[j] counts them all).
   Branch-free where it can be (the counts vectorise); the rare values inside a window are
   flagged first, then kept. */
#define SUB 1024

void toggle_mc_accumulate(long start, long n, const double *restrict lower,
                          const double *restrict upper, const double *restrict nominal,
                          const double *restrict shift, long block, double *restrict sums,
                          const double *restrict lo, const double *restrict hi,
                          int64_t *restrict below, double *restrict kept,
                          const int64_t *restrict base, const int64_t *restrict cap,
                          int64_t *restrict filled)
{
    for (long t = 0; t < n; t += SUB) {
        const long m = n - t < SUB ? n - t : SUB;
        double v[3][SUB];
        for (long i = 0; i < m;) {
            const long b = (start + t + i) / block;
            const long end = (b + 1) * block - start - t < m ? (b + 1) * block - start - t : m;
            double s[6];
            for (int k = 0; k < 6; k++)
                s[k] = sums[6 * b + k];
            for (; i < end; i++) {
                const double lw = lower[t + i], up = upper[t + i];
                v[0][i] = lw - nominal[0];
                v[1][i] = up - nominal[1];
                v[2][i] = up - lw;
                for (int o = 0; o < 3; o++) {
                    const double d = v[o][i] - shift[o];
                    s[2 * o] += d;
                    s[2 * o + 1] += d * d;
                }
            }
            for (int k = 0; k < 6; k++)
                sums[6 * b + k] = s[k];
        }
        for (int o = 0; o < 3; o++) {
            const double *w = v[o];
            const double *l = lo + o * N_QUANTILES, *h = hi + o * N_QUANTILES;
            for (int k = 0; k < N_QUANTILES; k++) {
                int64_t c = 0;
                for (long i = 0; i < m; i++)
                    c += w[i] < l[k];
                below[o * N_QUANTILES + k] += c;
            }
            unsigned char in[SUB];
            for (long i = 0; i < m; i++) {
                int f = 0;
                for (int k = 0; k < N_QUANTILES; k++)
                    f |= (w[i] >= l[k]) & (w[i] <= h[k]);
                in[i] = (unsigned char)f;
            }
            for (long i = 0; i < m; i++) {
                if (!in[i])
                    continue;
                for (int k = 0; k < N_QUANTILES; k++) {
                    const int j = o * N_QUANTILES + k;
                    if (w[i] >= l[k] && w[i] <= h[k]) {
                        if (filled[j] < cap[j])
                            kept[base[j] + filled[j]] = w[i];
                        filled[j]++;
                    }
                }
            }
        }
    }
}

/* The draws themselves (dimensions x n), for the tests' comparison with numpy. */
void toggle_mc_draws(long start, long n, uint32_t k0, uint32_t k1, uint32_t stream,
                     int normal, double *restrict out)
{
    for (long i = 0; i < n; i++) {
        double d[N_DIMS];
        toggle_draws_at((uint64_t)(start + i), k0, k1, stream, normal, d);
        for (int k = 0; k < N_DIMS; k++)
            out[k * n + i] = d[k];
    }
}

/* One Philox4x32-10 block, for the known-answer tests. */
void toggle_philox4x32(const uint32_t *counter, const uint32_t *key, uint32_t *out)
{
    uint32_t c[4] = {counter[0], counter[1], counter[2], counter[3]};
    philox4x32_10(c, key[0], key[1]);
    for (int w = 0; w < 4; w++)
        out[w] = c[w];
}
"""

_COMMON = ("-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
           "-ffp-contract=off", f"-DN_DIMS={len(DIMENSIONS)}", f"-DN_QUANTILES={len(QUANTILES)}")
#: Builds tried in turn: vectorised with libmvec for this CPU, then plain scalar C.
_VARIANTS = (
    ((*_COMMON, "-O3", "-march=native", "-fno-math-errno", "-fno-trapping-math",
      "-fno-semantic-interposition", "-finline-limit=100000", "-fno-builtin-sin",
      "-fno-builtin-cos", "-DTOGGLE_LIBMVEC"), ("-lmvec", "-lm")),
    ((*_COMMON, "-O2", "-fno-math-errno"), ("-lm",)),
)
_ARRAY = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")


_U32 = ctypes.c_uint32
_WORDS = np.ctypeslib.ndpointer(dtype=np.uint32, flags="C_CONTIGUOUS")
_LONGS = np.ctypeslib.ndpointer(dtype=np.int64, flags="C_CONTIGUOUS")
_DRAWS = (ctypes.c_long, ctypes.c_long, _U32, _U32, _U32, ctypes.c_int)


def _function(library: ctypes.CDLL, name: str, restype: object, *argtypes: object) -> object:
    fn = getattr(library, name)
    fn.restype, fn.argtypes = restype, list(argtypes)
    return fn


class Kernel:
    """The loaded kernel: :meth:`sampled` halves drawn in C, or :meth:`outputs` of given
    draws; :meth:`draws` and :meth:`philox4x32` expose its generator to the tests."""

    def __init__(self, library: Path) -> None:
        lib = ctypes.CDLL(str(library))
        self._fn = _function(lib, "toggle_mc_half", ctypes.c_long, ctypes.c_long,
                             ctypes.c_double, _ARRAY, _ARRAY, _ARRAY, _ARRAY)
        self._sampled = _function(lib, "toggle_mc_sampled", ctypes.c_long, *_DRAWS,
                                  ctypes.c_double, _ARRAY, _ARRAY, _ARRAY)
        self._draws = _function(lib, "toggle_mc_draws", None, *_DRAWS, _ARRAY)
        self.accumulate = _function(lib, "toggle_mc_accumulate", None, ctypes.c_long,
                                    ctypes.c_long, _ARRAY, _ARRAY, _ARRAY, _ARRAY,
                                    ctypes.c_long, _ARRAY, _ARRAY, _ARRAY, _LONGS, _ARRAY,
                                    _LONGS, _LONGS, _LONGS)
        """:mod:`toggle.mc_summary`'s accumulation in C (its arguments: that module's)."""
        self._philox = _function(lib, "toggle_philox4x32", None, _WORDS, _WORDS, _WORDS)

    def sampled(self, x: float, nominal: np.ndarray, scale: np.ndarray, key: philox.Key,
                start: int, stream: int, distribution: str, out: np.ndarray) -> int:
        """Output positions L (m) at x of samples ``start .. start + len(out) - 1`` of
        ``stream`` (:mod:`toggle.philox`'s draws, made in C), written into ``out`` (float64,
        contiguous); returns how many are not finite."""
        nominal, scale = self._checked(nominal, scale)
        return int(self._sampled(start, out.size, *key, stream, distribution == "normal",
                                 float(x), nominal, scale, out))

    def draws(self, key: philox.Key, start: int, n: int, stream: int, distribution: str
              ) -> np.ndarray:
        """The draws :meth:`sampled` makes (dimensions x n), as :func:`toggle.philox.draws`."""
        out = np.empty((len(DIMENSIONS), n))
        self._draws(start, n, *key, stream, distribution == "normal", out)
        return out

    def philox4x32(self, counter: tuple[int, ...], key: philox.Key) -> tuple[int, ...]:
        """One Philox4x32-10 block of the C generator."""
        out = np.empty(4, dtype=np.uint32)
        self._philox(np.array(counter, dtype=np.uint32), np.array(key, dtype=np.uint32), out)
        return tuple(int(w) for w in out)

    @staticmethod
    def _checked(nominal: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nominal, scale = (np.ascontiguousarray(a, dtype=np.float64) for a in (nominal, scale))
        if nominal.shape != (len(DIMENSIONS),) or scale.shape != nominal.shape:
            raise ValueError(f"expected {len(DIMENSIONS)} nominal values and scales, got "
                             f"{nominal.shape}, {scale.shape}")
        return nominal, scale

    def outputs(self, x: float, nominal: np.ndarray, scale: np.ndarray, draws: np.ndarray
                ) -> tuple[np.ndarray, int]:
        """Output positions L (m) of the halves ``nominal + scale[:, None] * draws`` at x
        and how many of them are not finite."""
        nominal, scale = self._checked(nominal, scale)
        draws = np.ascontiguousarray(draws, dtype=np.float64)
        if draws.ndim != 2 or draws.shape[0] != len(DIMENSIONS):
            raise ValueError(f"expected draws of shape ({len(DIMENSIONS)}, n), got "
                             f"{draws.shape}")
        out = np.empty(draws.shape[1])
        bad = self._fn(draws.shape[1], float(x), nominal, scale, draws, out)
        return out, int(bad)


def _generated() -> ca.Function:
    """The CasADi function (x, dims) -> L of the one kinematics."""
    x = ca.SX.sym("x")
    p = ca.SX.sym("p", len(DIMENSIONS))
    L = ca.SX(output_position(x, [p[i] for i in range(len(DIMENSIONS))]))
    return ca.Function("kinematics", [x, p], [L])


def _cpu() -> str:
    """This CPU's identity (builds use -march=native): its model and instruction sets."""
    try:
        info = Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines()
        return "\n".join(sorted({line for line in info
                                 if line.startswith(("model name", "flags"))}))
    except OSError:
        return platform.processor()


def _sources(flags: tuple[str, ...]) -> tuple[str, Callable[[Path], Sources]]:
    """Cache key (the C text, flags, CPU) and the writer of the sources."""
    kinematics = casadi_c("kinematics.c", [_generated()])  # the name the driver includes

    def write(tmp: Path) -> Sources:
        (tmp / "kinematics.c").write_text(kinematics, encoding="utf-8")
        (tmp / "philox.c").write_text(philox.C_SOURCE, encoding="utf-8")
        driver = tmp / "mc_kernel.c"
        driver.write_text(_DRIVER, encoding="utf-8")
        return [(flags, driver)]

    key = hashlib.sha256("\0".join((kinematics, philox.C_SOURCE, _DRIVER, *flags, _cpu())).encode())
    return key.hexdigest(), write


def _load(library: Path) -> Kernel | None:
    try:
        return Kernel(library)
    except (OSError, AttributeError):
        return None


@functools.cache
def load() -> Kernel | None:
    """The compiled kernel, built on first use; None (with a warning) without a compiler."""
    for flags, libs in _VARIANTS:
        key, write = _sources(flags)
        kernel = shared_library("mc_kernel", key, write, _load, libs)
        if kernel is not None:
            return kernel
    warnings.warn(f"no working C compiler (CC={os.environ.get('CC', 'gcc')}): the Monte Carlo's "
                  "kinematics run in numpy (same results, slower)", stacklevel=2)
    return None
