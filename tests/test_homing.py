"""Homing's constant-speed points, made as they are streamed (hil.host.homing.ConstantSpeed)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.host.homing import ConstantSpeed
from hil.link import protocol as p


@given(start=st.integers(-10**6, 10**6), per_period=st.floats(-20, 20),
       count=st.integers(0, 300), a=st.integers(-400, 400), b=st.integers(-400, 400))
def test_the_move_reads_as_the_list_it_replaces(start: int, per_period: float, count: int,
                                                a: int, b: int) -> None:
    listed = [(start + round(per_period * (i + 1)), p.NO_CHECK) for i in range(count)]
    move = ConstantSpeed(start, per_period, count)
    assert len(move) == len(listed) and bool(move) == bool(listed)
    assert move[a:b] == listed[a:b] and move[a:] == listed[a:]
    if -count <= a < count:
        assert move[a] == listed[a]
    else:
        with pytest.raises(IndexError):
            move[a]
