"""CONFIG and the stored calibration against both MCUs (docs/rig-protocol.md §5, versions 1.2
and 1.3): a calibration override for one session, the step limit, the deceleration, the re-check
of the buffered points, STORE_CALIBRATION and READ_CALIBRATION.

As tests/test_mcu_conformance.py: every test runs on the Python MCU model and on the C
firmware's host build through the bench of tests/mcu_bench.py, and the ``..._on_both`` tests
compare their answers.
"""

from __future__ import annotations

import mcu_bench
import numpy as np
import pytest
from calibration_script import EXPECTED, calibration_script
from mcu_bench import HAVE_GCC, Bench

from hil.link import protocol as p

kind, bench = mcu_bench.kind, mcu_bench.bench  # the bench's fixtures, for pytest


def test_a_calibration_override_lasts_one_session(kind: str) -> None:
    b = Bench(kind).session(load_offset=0, load_gain_n=2e-4)
    assert b.ack(p.Bye()).result == p.Result.OK
    reply = b.send(p.Hello(1, 1, 43))[0]
    assert (reply.load_offset, reply.load_gain_n) == (1500, pytest.approx(1e-4, rel=1e-6))


def test_the_step_limit_is_stated_and_a_config_above_it_refused(kind: str) -> None:
    """1.3: HELLO_REPLY states the most steps a period may hold (the NUCLEO's TIM1 burst, 256)
    and CONFIG refuses a larger max_step_delta as BAD_VALUE, the same on the model and the
    firmware (the image answered such a CONFIG OK, then latched INTERNAL at START)."""
    b = Bench(kind)
    reply = b.ack(p.Hello(1, p.PROTO_MINOR, 42))
    assert reply.max_step_delta_limit == p.MAX_STEP_DELTA == 256
    assert b.ack(p.Config(max_step_delta=257)).result == p.Result.BAD_VALUE
    assert b.ack(p.Config(max_step_delta=65_535)).result == p.Result.BAD_VALUE
    assert b.ack(p.Config(max_step_delta=256)).result == p.Result.OK


def test_a_deceleration_that_never_stops_is_refused(bench: Bench) -> None:
    assert bench.ack(p.Config(decel_steps_s2=7.0)).result == p.Result.BAD_VALUE
    assert bench.ack(p.Config(decel_steps_s2=8.0)).result == p.Result.OK


def config_after_upload(kind: str) -> list[tuple[str, p.Result]]:
    """Issue 35's case: 200-step jumps buffered under max_step_delta 256 (the most a board
    emits in a period, 1.3), then CONFIGs that the buffered points break (a smaller
    max_step_delta, narrower travel) and one they obey; (what was sent, the answer) in
    order, and the first run sample's steps."""
    b = Bench(kind).session(max_step_delta=p.MAX_STEP_DELTA)
    b.load([(200, p.NO_CHECK), (400, p.NO_CHECK), (600, p.NO_CHECK)])
    cases = {"max_step_delta 150": dict(max_step_delta=150),
             "max_step_delta 199 (point 0 from the table)": dict(max_step_delta=199),
             "steps_max 599": dict(max_step_delta=p.MAX_STEP_DELTA, steps_max=599),
             "max_step_delta 200, steps_max 600": dict(max_step_delta=200, steps_max=600)}
    answers = [(name, p.Result(b.ack(p.Config(stuck_samples=60_000, **cfg)).result))
               for name, cfg in cases.items()]
    assert b.ack(p.Start()).result == p.Result.OK
    answers.append(("first run sample's steps", b.tick().steps))
    return answers


def test_a_config_re_checks_the_buffered_points(kind: str) -> None:
    """Version 1.2 (docs/rig-protocol.md, section 5): a CONFIG whose limits a buffered point
    breaks is refused as that chunk would be, and nothing changes."""
    answers = dict(config_after_upload(kind))
    assert list(answers.values()) == [p.Result.BAD_VALUE, p.Result.BAD_VALUE,
                                      p.Result.OUT_OF_LIMITS, p.Result.OK, 200], answers


@pytest.mark.skipif(not HAVE_GCC, reason="the firmware's host build needs gcc (Debian gcc)")
def test_the_config_re_check_is_the_same_on_both() -> None:
    assert config_after_upload("model") == config_after_upload("firmware")


def stored_calibration_answers(kind: str) -> list[tuple[object, ...]]:
    """tests/calibration_script.py on one MCU; its reboot is an MCU reset (the non-volatile
    memory survives it: the model's, the host build's memory or file)."""
    b = Bench(kind).session()

    def reboot() -> p.HelloReply:
        b.mcu.reset()
        return b.send(p.Hello(1, 3, 44))[0]  # type: ignore[return-value]

    return calibration_script(b.ack, reboot)


def test_the_stored_calibration_commands(kind: str) -> None:
    """STORE_CALIBRATION and READ_CALIBRATION (1.3): refusals, record numbers, the stored
    calibration in use after a reset, refused without a session."""
    assert stored_calibration_answers(kind) == EXPECTED


@pytest.mark.skipif(not HAVE_GCC, reason="the firmware's host build needs gcc (Debian gcc)")
def test_the_stored_calibration_is_the_same_on_both() -> None:
    assert stored_calibration_answers("model") == stored_calibration_answers("firmware")


def config_answers_over_a_full_buffer(kind: str, seed: int) -> list[int]:
    """A full buffer (2048 points, walks of up to 256 steps a period with one long jump and
    one far point at random places), then CONFIGs whose limits cut at the buffer's own
    values, so the first failure lands in any block and both kinds meet in one: the
    answers in order (the firmware reads only the block its summaries point at)."""
    rng = np.random.default_rng(seed)
    n = 2048  # the buffer's capacity
    jumps = rng.integers(-100, 101, n)
    big = 64 * int(rng.integers(1, n // 64))  # a block's first point: its jump is read apart
    far = int(rng.choice(np.setdiff1d(np.arange(1, n - 1), [big - 1, big, big + 1])))
    jumps[big] = 256 * rng.choice([-1, 1])
    jumps[far] += 150  # a point out of the walk's way: one jump up, the next down
    jumps[far + 1] -= 150
    steps = np.cumsum(jumps)
    assert np.abs(np.diff(np.concatenate(([0], steps)))).max() <= p.MAX_STEP_DELTA
    b = Bench(kind).session(max_step_delta=p.MAX_STEP_DELTA, steps_min=-200_000,
                            steps_max=400_000)
    b.load([(int(s), p.NO_CHECK) for s in steps], final=False)
    diffs = np.abs(np.diff(np.concatenate(([0], steps))))
    answers = []
    top = np.sort(diffs)[-3:]
    for k in range(16):
        if k % 2:  # travel wide: the jumps decide, around the largest ones
            ack = b.ack(p.Config(stuck_samples=60_000, steps_min=-100_000, steps_max=100_000,
                                 max_step_delta=int(rng.choice(top))))
            answers.append(int(ack.result))
            continue
        lo = min(int(rng.choice(steps)), 0) - int(rng.integers(0, 2)) * 100_000
        hi = max(int(rng.choice(steps)), 0) + int(rng.integers(0, 2)) * 100_000
        delta = int(min(max(int(rng.choice(diffs)), 1), p.MAX_STEP_DELTA))
        ack = b.ack(p.Config(stuck_samples=60_000, steps_min=lo, steps_max=max(hi, lo + 1),
                             max_step_delta=delta))
        answers.append(int(ack.result))
    return answers


@pytest.mark.skipif(not HAVE_GCC, reason="the firmware's host build needs gcc (Debian gcc)")
@pytest.mark.parametrize("seed", range(4))
def test_a_config_over_a_full_buffer_answers_as_the_loop(seed: int) -> None:
    """The firmware's block summaries give the model's loop's answer: OUT_OF_LIMITS or
    BAD_VALUE for the first failing point, OK when none fails."""
    model = config_answers_over_a_full_buffer("model", seed)
    assert set(model) == {p.Result.OK, p.Result.OUT_OF_LIMITS, p.Result.BAD_VALUE}, model
    assert config_answers_over_a_full_buffer("firmware", seed) == model
