"""The host's timeouts from the measured link (hil/link/timing.py,
docs/rig-protocol-behaviour.md §7)."""

from __future__ import annotations

import pytest

from hil.link.timing import (
    ACK_TIMEOUT_MAX,
    ACK_TIMEOUT_MIN,
    HEARTBEAT_MAX_MS,
    HEARTBEAT_MIN_MS,
    WATCHDOG_MAX,
    WATCHDOG_MIN,
    AckTimer,
    LinkTiming,
)


def timing(trip: float, rate: float, gap: float) -> LinkTiming:
    return LinkTiming((trip / 2, trip, trip / 3), rate, gap, 0.25, 250)


def test_a_rigs_idle_link_gets_the_protocols_timeouts() -> None:
    """Round trips of a few ms, the MCU keeping wall time (as measured, a little off)."""
    for rate in (0.93, 1.0, 1.04):
        t = timing(4e-3, rate, 6e-3)
        assert (t.ack_timeout, t.telemetry_timeout, t.heartbeat_timeout_ms) == (
            ACK_TIMEOUT_MIN, WATCHDOG_MIN, HEARTBEAT_MIN_MS)
        assert t.is_nominal


def test_a_slow_emulator_gets_longer_timeouts_within_the_bounds() -> None:
    t = timing(30e-3, 0.4, 20e-3)
    assert t.ack_timeout == pytest.approx(4 * 30e-3)
    # 100 ms of the MCU's clock is 250 ms of the wall clock; 4 ACK timeouts are more
    assert t.telemetry_timeout == pytest.approx(max(0.1 / 0.4, 8 * 20e-3, 4 * 0.12))
    assert t.heartbeat_timeout_ms == min(round(2.5 * t.telemetry_timeout * 1e3), HEARTBEAT_MAX_MS)
    assert not t.is_nominal
    worst = timing(2.0, 0.01, 1.0)
    assert (worst.ack_timeout, worst.telemetry_timeout, worst.heartbeat_timeout_ms) == (
        ACK_TIMEOUT_MAX, WATCHDOG_MAX, HEARTBEAT_MAX_MS)


def test_the_mcu_waits_for_the_host_at_least_as_long_as_the_host_waits_for_it() -> None:
    """In wall time the MCU's heartbeat timeout (its own clock, no faster than the wall
    clock) is never below the host's telemetry watchdog."""
    for trip in (1e-3, 10e-3, 50e-3, 0.3):
        for rate in (0.05, 0.3, 0.7, 1.0):
            for gap in (1e-3, 30e-3, 0.2):
                t = timing(trip, rate, gap)
                assert t.heartbeat_timeout_ms / 1e3 >= t.telemetry_timeout
                assert t.heartbeat_timeout_ms / 1e3 / t.rate >= t.telemetry_timeout


def test_the_ack_timer_follows_slower_round_trips_and_keeps_its_floor() -> None:
    timer = AckTimer(0.04)
    for _ in range(20):
        timer.add(2e-3)  # a quick link: the measured floor stays
    assert timer.timeout == 0.04
    for _ in range(5):
        timer.add(0.1)  # the link slowed down: the timeout grows past the round trip
    assert 0.1 < timer.timeout <= ACK_TIMEOUT_MAX
    for _ in range(50):
        timer.add(5.0)
    assert timer.timeout == ACK_TIMEOUT_MAX


def test_the_measurement_is_described_for_the_record() -> None:
    t = timing(30e-3, 0.4, 20e-3)
    info = t.describe()
    assert info["mcu_clock_rate"] == 0.4 and max(info["hello_round_trips_s"]) == 30e-3
    assert "40 %" in t.text() and "30.0 ms" in t.text()
