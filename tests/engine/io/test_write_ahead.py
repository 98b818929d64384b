"""``WriteAhead``: writes run in a second thread, at most ``ahead`` waiting; what follows each runs in the caller's
thread in the order submitted; a failed write surfaces in the caller; leaving by an exception starts no queued write
and waits for the one under way."""

from __future__ import annotations

import threading
import time

import pytest

from engine.io.write_ahead import WriteAhead


def test_writes_finish_in_order_in_the_callers_thread_with_at_most_ahead_waiting():
    caller = threading.get_ident()
    done: list[tuple[int, int, int]] = []  # (tag, result, thread that ran done)
    started: list[tuple[int, int]] = []  # (tag, thread that wrote it)
    waiting: list[int] = []

    def write(k: int) -> int:
        started.append((k, threading.get_ident()))
        time.sleep(0.01 * (k % 3))  # uneven write times
        return k * k

    with WriteAhead[int](2, lambda tag, result: done.append((tag, result, threading.get_ident()))) as writer:
        for k in range(8):
            writer.submit(k, write, k)
            waiting.append(k + 1 - len(done))
    assert [(tag, result) for tag, result, _ in done] == [(k, k * k) for k in range(8)]
    assert {thread for _, _, thread in done} == {caller}
    assert max(waiting) <= 2 and [k for k, _ in started] == list(range(8))
    assert caller not in {thread for _, thread in started}  # every write in the writer's thread


def test_ahead_zero_writes_each_before_the_next_is_submitted():
    done: list[int] = []
    with WriteAhead[None](0, lambda tag, _: done.append(tag)) as writer:
        for k in range(4):
            writer.submit(k, time.sleep, 0.001)
            assert done == list(range(k + 1))


def test_a_failed_write_is_raised_in_the_caller_and_nothing_after_it_is_written():
    written: list[int] = []

    def write(k: int) -> None:
        if k == 2:
            raise OSError(28, "No space left on device")
        written.append(k)

    with pytest.raises(OSError, match="No space left"), WriteAhead[None](1, lambda *_: None) as writer:
        for k in range(6):
            writer.submit(k, write, k)
            time.sleep(0.02)  # the write of k is over before k + 1 is computed
    assert written == [0, 1]


def test_leaving_by_an_exception_waits_for_the_write_under_way_and_starts_none_queued():
    release = threading.Event()
    started: list[int] = []
    finished: list[int] = []

    def write(k: int) -> None:
        started.append(k)
        if k == 0:
            release.wait(5)
        finished.append(k)

    class Cancelled(Exception):
        pass

    timer = threading.Timer(0.2, release.set)
    timer.start()
    with pytest.raises(Cancelled), WriteAhead[None](3, lambda *_: None) as writer:
        for k in range(3):
            writer.submit(k, write, k)
        raise Cancelled  # a SIGTERM while write 0 is under way and 1, 2 are queued
    timer.cancel()
    assert started == [0] and finished == [0]  # the write under way ended whole; the queued ones never began
