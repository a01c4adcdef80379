"""Telemetry over the pseudo-terminal at 1 kHz: sustained rate, lost frames, host latency.

The rig emulator runs in its own process (as `hil emulate` does). The MCU stamps its
samples in us since its boot, so the latency from the MCU building a sample to the
consumer taking it from the link's queue is measured above the smallest one seen. A
trajectory runs during the measurement, so chunk streaming and acknowledgements share the
link with the telemetry.

    python benchmarks/bench_telemetry.py [--seconds 5] [--realtime]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hil.emulators.rig_emulator import spawn_emulator
from hil.link import protocol as p
from hil.link.serial_link import SerialLink


class LinearPlant:
    """Benchmark-only stand-in plant (platen = 2 x, force = 2 kN/m x); timing only."""

    def __call__(self, x: float, t: float) -> tuple[float, float]:
        return 2.0 * x, 2e3 * x


def measure(seconds: float, realtime: bool) -> dict[str, float]:
    """Run a `seconds`-long trajectory and return the telemetry statistics."""
    n = int(seconds * 1000)
    points = [(round(20 * i), p.NO_CHECK) for i in range(n)]  # 4 mm/s ramp
    with spawn_emulator(LinearPlant(), realtime=realtime) as emulator, \
            SerialLink(emulator.port, telemetry_timeout=1.0, realtime=realtime) as link:
        link.open()
        latency, samples = [], []
        t0 = time.monotonic()
        for tel in link.run_trajectory(points):
            latency.append(time.monotonic() * 1e3 - tel.t_us / 1e3)
            samples.append(tel)
        wall = time.monotonic() - t0
        span = samples[-1].rx_time - samples[0].rx_time
        lat = np.array(latency) - min(latency)  # above the smallest: the clocks differ
        rx_gaps = np.diff([s.rx_time for s in samples]) * 1e3
        return {
            "samples": len(samples),
            "rate_hz": (len(samples) - 1) / span,
            "lost": link.stats.lost_samples,
            "crc_rejected": link.decoder.stats.rejected,
            "retransmissions": link.stats.retransmissions,
            "wall_s": wall,
            "lat_p50_ms": float(np.percentile(lat, 50)),
            "lat_p90_ms": float(np.percentile(lat, 90)),
            "lat_p99_ms": float(np.percentile(lat, 99)),
            "lat_max_ms": float(lat.max()),
            "gap_max_ms": float(rx_gaps.max()),
            "gaps_over_3ms": int((rx_gaps > 3.0).sum()),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--realtime", action="store_true",
                        help="SCHED_FIFO for the emulator and the host reader (if permitted)")
    args = parser.parse_args()
    r = measure(args.seconds, args.realtime)
    print(f"telemetry over pty, {args.seconds:g} s, realtime={args.realtime}")
    print(f"  samples {r['samples']}  sustained rate {r['rate_hz']:.1f} Hz  "
          f"lost {r['lost']}  rejected frames {r['crc_rejected']}  "
          f"retransmissions {r['retransmissions']}")
    print(f"  host latency ms: p50 {r['lat_p50_ms']:.3f}  p90 {r['lat_p90_ms']:.3f}  "
          f"p99 {r['lat_p99_ms']:.3f}  max {r['lat_max_ms']:.3f}")
    print(f"  receive gaps: max {r['gap_max_ms']:.2f} ms, {r['gaps_over_3ms']} over 3 ms")


if __name__ == "__main__":
    main()
