"""The background threads of the run loop: order, errors, and stopping."""

import threading
import time

import pytest

from eponet.core.prefetch import Prefetch, Stopped, wait_for


def test_items_arrive_in_order_and_an_upstream_error_after_them():
    def upstream():
        yield from range(5)
        raise ValueError("frame 5 is corrupt")

    received = []
    with pytest.raises(ValueError, match="frame 5"):
        for item in Prefetch(upstream(), 2, "test"):
            received.append(item)
    assert received == [0, 1, 2, 3, 4]


def test_start_runs_ahead_by_at_most_depth_items():
    produced = []

    def upstream():
        for k in range(10):
            produced.append(k)
            yield k

    ahead = Prefetch(upstream(), 3, "test").start()
    time.sleep(0.3)
    assert 3 <= len(produced) <= 4  # 3 queued, one more waiting to be put
    assert list(ahead) == list(range(10))


def test_close_stops_the_thread_and_runs_the_upstream_finally():
    cleaned = threading.Event()

    def upstream():
        try:
            k = 0
            while True:
                yield k
                k += 1
        finally:
            cleaned.set()

    ahead = Prefetch(upstream(), 2, "test-close")
    assert next(ahead) == 0
    ahead.close()
    assert cleaned.is_set()
    assert not [t for t in threading.enumerate() if t.name == "eponet-test-close"]
    with pytest.raises(Stopped):  # not an end: a consumer must not take a stopped video for a finished one
        next(ahead)


def test_wait_for_ends_when_cancelled():
    event, cancelled = threading.Event(), threading.Event()
    threading.Timer(0.15, cancelled.set).start()
    assert wait_for(event, cancelled, poll=0.05) is False
    event.set()
    assert wait_for(event, threading.Event()) is True


def test_a_consumer_waiting_in_another_thread_is_told_that_the_producer_stopped():
    def endless():
        k = 0
        while True:
            yield k
            k += 1
            time.sleep(0.01)

    flow = Prefetch(endless(), 2, "test-stopped")
    seen = []

    def consume():
        try:
            for item in flow:
                seen.append(item)
        except Stopped as exc:
            seen.append(exc)

    consumer = threading.Thread(target=consume)
    consumer.start()
    time.sleep(0.2)
    flow.close()
    consumer.join(timeout=2)
    assert not consumer.is_alive() and isinstance(seen[-1], Stopped) and seen[:3] == [0, 1, 2]
