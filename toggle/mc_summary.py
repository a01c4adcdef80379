"""A Monte Carlo's statistics in one pass, without keeping its samples.

The mean, σ and exact percentiles of each output (the lower and upper halves' errors
L - L_nominal and the asymmetry L_upper - L_lower) of a run of n samples, accumulated
chunk by chunk as the samples are made (:class:`Summary`), in C by the compiled kernel
(:mod:`toggle.mc_kernel`'s ``toggle_mc_accumulate``) or by the same operations in numpy:

* Mean and σ from the sums of d = v - shift and d² (shift: the pilot's mean, so that a
  mean far from zero costs σ no digits), each block of :data:`BLOCK` samples summed in
  sample order whatever the chunks, the blocks added exactly (``math.fsum``): a run's
  result does not depend on its chunk size, and C and numpy give the same bits.
* The percentiles are order statistics, selected exactly: the first :data:`PILOT`
  samples (the pilot) place a window around each percentile, WINDOW_Z of its standard
  errors wide; the pass counts the values below each window and keeps those inside, and
  the order statistics are selected among those (a few hundred thousand of ten million).
  Where a window missed its rank (a chance below 1e-6 each) or held more than its
  room (many tied values), :meth:`Summary.statistics` leaves that output's percentiles
  out and the caller selects them from all the samples, as :func:`percentiles` does: the
  same values either way, the values of ``np.percentile``.

Keeping no samples is what makes ``toggle tolerance --samples 1e7`` fast: three arrays of
80 MB cost more in page faults and passes than the kernel's draws and kinematics.
"""

from __future__ import annotations

import math

import numpy as np

#: The percentiles a Monte Carlo reports: +-3 sigma, +-1.96 sigma of a normal, the median.
QUANTILES = (0.135, 2.5, 50.0, 97.5, 99.865)
#: The outputs summarised, in this order (the C kernel's too).
OUTPUTS = ("lower", "upper", "asymmetry")
#: Samples per block of the sums.
BLOCK = 4096
#: Samples of the pilot that places the percentile windows.
PILOT = 65_536
#: Half-width of a window in standard errors of the pilot's quantile, sqrt(m p (1-p)) ranks.
WINDOW_Z = 7.0


def _order_statistics(values: np.ndarray, ranks: list[int], found: dict[int, float],
                      offset: int = 0) -> None:
    """The values of the given ranks (and each rank + 1) of ``values`` into ``found``,
    partitioning in place around the middle rank and recursing on each side: about 2.5
    passes for the five quantiles, where one np.partition with all ten ranks makes seven
    (it selects each rank afresh over what lies to its right)."""
    if not ranks:
        return
    mid = ranks[len(ranks) // 2]
    values.partition(mid)
    found[offset + mid] = float(values[mid])
    if mid + 1 < values.size:
        found[offset + mid + 1] = float(values[mid + 1:].min())
    _order_statistics(values[:mid], [r for r in ranks if r < mid], found, offset)
    _order_statistics(values[mid + 1:], [r - mid - 1 for r in ranks if r > mid], found,
                      offset + mid + 1)


def _ranks(n: int, qs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """np.percentile's linear method: each quantile's virtual index, and the ranks below
    and above it."""
    virtual = (n - 1) * np.true_divide(qs, 100)
    below = np.floor(virtual).astype(np.intp)
    return virtual, below, np.minimum(below + 1, n - 1)


def _lerp(virtual: np.ndarray, below: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    t = virtual - below
    diff = b - a  # numpy's lerp: from the nearer end
    return np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)


def percentiles(values: np.ndarray, qs: tuple[float, ...] = QUANTILES) -> np.ndarray:
    """``np.percentile(values, qs)`` (its default linear method, the same bits) for finite
    values, which are reordered in place: a Monte Carlo's ten million outputs in a third of
    its time."""
    virtual, below, above = _ranks(values.size, qs)
    found: dict[int, float] = {}
    _order_statistics(values, sorted(set(below.tolist())), found)
    return _lerp(virtual, below, np.array([found[i] for i in below]),
                 np.array([found[i] for i in above]))


class Summary:
    """The statistics of a run of ``n`` samples, accumulated by :meth:`add` in any chunks,
    the first of them the pilot (``lower``, ``upper``: its outputs L of each half, the
    first ``min(n, PILOT)`` samples; ``nominal``: each half's nominal L)."""

    def __init__(self, n: int, nominal: tuple[float, float], lower: np.ndarray,
                 upper: np.ndarray, qs: tuple[float, ...] = QUANTILES) -> None:
        self.n, self.qs, w = n, qs, len(qs)
        self.nominal = np.array(nominal, dtype=np.float64)
        self.sums = np.zeros(((n + BLOCK - 1) // BLOCK, len(OUTPUTS), 2))
        self.lo, self.hi = np.empty(len(OUTPUTS) * w), np.empty(len(OUTPUTS) * w)
        cap = np.empty(len(OUTPUTS) * w, dtype=np.int64)
        m = lower.size
        pilot = self.values(lower, upper)
        self.shift = np.array([float(v.mean()) for v in pilot])
        for o, v in enumerate(pilot):
            ordered = np.sort(v)
            for k, q in enumerate(qs):
                p, j = q / 100, o * w + k
                spread = 0.0 if m == n else WINDOW_Z * math.sqrt(m * p * (1 - p))
                first = math.floor((m - 1) * p - spread) - 1
                last = math.ceil((m - 1) * p + spread) + 2
                self.lo[j] = -np.inf if first < 0 else ordered[first]
                self.hi[j] = np.inf if last > m - 1 else ordered[last]
                cap[j] = int(1.5 * (min(last, m - 1) - max(first, 0) + 1) * n / m) + 1024
        self.cap = cap
        self.base = np.concatenate(([0], np.cumsum(cap)[:-1])).astype(np.int64)
        self.kept = np.empty(int(cap.sum()))
        self.below = np.zeros(cap.size, dtype=np.int64)
        self.filled = np.zeros(cap.size, dtype=np.int64)

    def values(self, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, ...]:
        """The outputs of samples from each half's L: the errors and the asymmetry."""
        return lower - self.nominal[0], upper - self.nominal[1], upper - lower

    def add(self, start: int, lower: np.ndarray, upper: np.ndarray, kernel: object = None
            ) -> None:
        """Add samples ``start ..`` (their outputs L of each half, finite), by ``kernel``
        (a :class:`toggle.mc_kernel.Kernel`) or by numpy: the same operations."""
        if kernel is not None:
            kernel.accumulate(start, lower.size, lower, upper, self.nominal, self.shift, BLOCK,
                              self.sums, self.lo, self.hi, self.below,
                              self.kept, self.base, self.cap, self.filled)
            return
        n, w = lower.size, len(self.qs)
        for o, v in enumerate(self.values(lower, upper)):
            d = v - self.shift[o]
            for b in range(start // BLOCK, (start + n - 1) // BLOCK + 1):
                part = slice(max(b * BLOCK, start) - start, min((b + 1) * BLOCK, start + n) - start)
                for k, terms in enumerate((d[part], d[part] * d[part])):  # in sample order
                    self.sums[b, o, k] = np.add.accumulate(
                        np.concatenate(([self.sums[b, o, k]], terms)))[-1]
            for j in range(o * w, (o + 1) * w):
                self.below[j] += np.count_nonzero(v < self.lo[j])
                inside = v[(v >= self.lo[j]) & (v <= self.hi[j])]
                room = max(int(self.cap[j] - self.filled[j]), 0)
                taken = inside[:room]
                at = int(self.base[j] + self.filled[j])
                self.kept[at:at + taken.size] = taken
                self.filled[j] += inside.size

    def statistics(self) -> dict[str, tuple[float, float, np.ndarray | None]]:
        """Each output's mean, σ (ddof 1) and percentiles, these None where a window missed
        (the caller then selects them from all the samples: :func:`percentiles`)."""
        n, w = self.n, len(self.qs)
        virtual, below, above = _ranks(n, self.qs)
        out = {}
        for o, name in enumerate(OUTPUTS):
            s, ss = math.fsum(self.sums[:, o, 0]), math.fsum(self.sums[:, o, 1])
            mean = self.shift[o] + s / n
            std = math.sqrt(max(ss - s * s / n, 0.0) / (n - 1))
            a, b = np.empty(w), np.empty(w)
            for k in range(w):
                j = o * w + k
                first, count = int(self.below[j]), int(self.filled[j])
                if count > self.cap[j] or not first <= below[k] < above[k] + 1 <= first + count:
                    a = None
                    break
                kept = self.kept[self.base[j]:self.base[j] + count].copy()
                lo, hi = int(below[k]) - first, int(above[k]) - first
                kept.partition([lo, hi] if hi != lo else [lo])
                a[k], b[k] = kept[lo], kept[hi]
            out[name] = (float(mean), std, None if a is None else _lerp(virtual, below, a, b))
        return out
