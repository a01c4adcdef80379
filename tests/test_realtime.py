"""hil.link.realtime: the session thread's priority is raised while a session runs, then put
back."""

from __future__ import annotations

import os
import threading

import pytest

from hil.link.realtime import SESSION_NICE, raise_thread_priority


def _nice() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def test_the_calling_thread_is_raised_and_restored_and_no_other() -> None:
    seen: dict[str, int] = {}

    def session() -> None:
        before = _nice()
        restore = raise_thread_priority()
        seen["during"], seen["other"] = _nice(), os.getpriority(os.PRIO_PROCESS, main_tid)
        restore()
        seen["before"], seen["after"] = before, _nice()

    main_tid = threading.get_native_id()
    main_nice = _nice()
    worker = threading.Thread(target=session)
    worker.start()
    worker.join()
    assert seen["after"] == seen["before"] and seen["other"] == main_nice
    try:  # a probe: whether this machine lets us raise a priority at all
        os.setpriority(os.PRIO_PROCESS, main_tid, SESSION_NICE)
        os.setpriority(os.PRIO_PROCESS, main_tid, main_nice)
    except PermissionError:
        assert seen["during"] == seen["before"]  # not permitted: nothing changes, no error
        pytest.skip("raising a priority needs root or CAP_SYS_NICE")
    assert seen["during"] == min(SESSION_NICE, seen["before"])


def test_a_thread_already_higher_is_left_as_it_is() -> None:
    seen: dict[str, int] = {}

    def session() -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), SESSION_NICE - 5)
        except PermissionError:
            return
        raise_thread_priority()()
        seen["after"] = _nice()

    worker = threading.Thread(target=session)
    worker.start()
    worker.join()
    if not seen:
        pytest.skip("raising a priority needs root or CAP_SYS_NICE")
    assert seen["after"] == SESSION_NICE - 5


def test_a_session_keeps_the_heap_out_of_collections_until_it_ends() -> None:
    import gc

    from hil.link.realtime import freeze_collections
    kept = [[i] for i in range(1000)]  # objects that exist when the session opens
    unfreeze = freeze_collections()
    try:
        assert gc.get_freeze_count() >= len(kept)
    finally:
        unfreeze()
    assert gc.get_freeze_count() == 0
