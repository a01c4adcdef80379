"""Compiled Monte Carlo kernel: the output position of a half for a whole array of samples.

The equations are not written here: CasADi generates C for
:func:`toggle.kinematics.output_position` (the one source of the clamp's equations) and
a small C driver loops over the samples, forming each sampled half as
``nominal + scale * draw`` (the same operations, in the same order, as numpy does) and
calling the generated function inlined. gcc vectorises that loop with glibc's vector
math library (libmvec: acos, asin, sin, cos four or eight at a time, within 4 ulp), which
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

from toggle.c_library import Sources, casadi_c, shared_library
from toggle.kinematics import output_position
from toggle.params import DIMENSIONS

_DRIVER = r"""
#include "kinematics.c"

/* glibc's vector variants (libmvec) of the functions the generated code calls. */
#ifdef TOGGLE_LIBMVEC
__attribute__((simd("notinbranch"), const)) double acos(double);
__attribute__((simd("notinbranch"), const)) double asin(double);
__attribute__((simd("notinbranch"), const)) double sin(double);
__attribute__((simd("notinbranch"), const)) double cos(double);
#endif

/* Output position of n sampled halves at input x: dimension k of sample i is
   nominal[k] + scale[k] * draws[k * n + i]. Returns how many outputs are not finite. */
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
        double p[N_DIMS];
        for (int k = 0; k < N_DIMS; k++)
            p[k] = nom[k] + sc[k] * draws[k * n + i];
        const casadi_real *arg[2] = {&x, p};
        casadi_real L;
        casadi_real *res[1] = {&L};
        casadi_f0(arg, res, 0, 0, 0);
        out[i] = L;
        bad += !(L - L == 0.0); /* NaN or infinite */
    }
    return bad;
}
"""

_COMMON = ("-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
           "-ffp-contract=off", f"-DN_DIMS={len(DIMENSIONS)}")
#: Builds tried in turn: vectorised with libmvec for this CPU, then plain scalar C.
_VARIANTS = (
    ((*_COMMON, "-O3", "-march=native", "-fno-math-errno", "-fno-trapping-math",
      "-fno-semantic-interposition", "-finline-limit=100000", "-fno-builtin-sin",
      "-fno-builtin-cos", "-DTOGGLE_LIBMVEC"), ("-lmvec", "-lm")),
    ((*_COMMON, "-O2", "-fno-math-errno"), ("-lm",)),
)
_ARRAY = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")


class Kernel:
    """The loaded kernel: :meth:`outputs` of sampled halves."""

    def __init__(self, library: Path) -> None:
        self._fn = ctypes.CDLL(str(library)).toggle_mc_half
        self._fn.restype = ctypes.c_long
        self._fn.argtypes = [ctypes.c_long, ctypes.c_double, _ARRAY, _ARRAY, _ARRAY, _ARRAY]

    def outputs(self, x: float, nominal: np.ndarray, scale: np.ndarray, draws: np.ndarray
                ) -> tuple[np.ndarray, int]:
        """Output positions L (m) of the halves ``nominal + scale[:, None] * draws`` at x
        and how many of them are not finite."""
        nominal, scale = (np.ascontiguousarray(a, dtype=np.float64) for a in (nominal, scale))
        draws = np.ascontiguousarray(draws, dtype=np.float64)
        if nominal.shape != (len(DIMENSIONS),) or scale.shape != nominal.shape or (
                draws.ndim != 2 or draws.shape[0] != len(DIMENSIONS)):
            raise ValueError(f"expected {len(DIMENSIONS)} nominal values and scales and "
                             f"draws of shape ({len(DIMENSIONS)}, n), got {nominal.shape}, "
                             f"{scale.shape}, {draws.shape}")
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
        driver = tmp / "mc_kernel.c"
        driver.write_text(_DRIVER, encoding="utf-8")
        return [(flags, driver)]

    key = hashlib.sha256("\0".join((kinematics, _DRIVER, *flags, _cpu())).encode())
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
