"""Zenoh's network thread (bus.participant, bus.config): callbacks run on it, it keeps its Python
state from one callback to the next, and it runs as SCHED_BATCH."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import pytest

from ringtrack.bus.config import BusConfig, listening_locators, open_session
from ringtrack.bus.participant import _direct

SAMPLES = 20


def deliver_samples(on_sample: Callable[[object], None], arrived: threading.Event, seen: list) -> None:
    """Publish ``SAMPLES`` samples, one callback each, to a subscriber of another session whose
    callback is ``on_sample`` (through :func:`_direct`, as a participant's); ``seen`` is what the
    callback appends to (cleared once the route is up), ``arrived`` what it sets at the last."""
    subscriber_session = open_session(BusConfig(listen=("tcp/127.0.0.1:0",), admin_space=True))
    try:
        publisher_session = open_session(BusConfig(connect=(listening_locators(subscriber_session)[0],)))
        try:
            subscriber = subscriber_session.declare_subscriber("ringtrack-test/thread", _direct(on_sample))
            publisher = publisher_session.declare_publisher("ringtrack-test/thread")
            deadline = time.monotonic() + 10.0
            while not seen and time.monotonic() < deadline:  # until the route is up
                publisher.put(b"first")
                time.sleep(0.05)
            seen.clear()
            for index in range(SAMPLES):
                publisher.put(b"%d" % index)
                time.sleep(0.005)  # one callback per sample
            assert arrived.wait(10.0), f"only {len(seen)} of {SAMPLES} samples arrived"
            subscriber.undeclare()
            publisher.undeclare()
        finally:
            publisher_session.close()
    finally:
        subscriber_session.close()


def test_the_network_thread_keeps_one_python_thread_state_across_callbacks() -> None:
    """Every sample is its own callback on Zenoh's thread; what that thread holds in a
    ``threading.local`` (which lives in the Python thread state) is still there at the next one, so
    the state is made once, not created and deleted (its stack mapped and unmapped) per sample."""
    held = threading.local()
    seen: list[tuple[int, int]] = []  # (thread, callbacks this thread state has run) per sample
    arrived = threading.Event()

    def on_sample(sample: object) -> None:
        held.count = getattr(held, "count", 0) + 1
        seen.append((threading.get_ident(), held.count))
        if len(seen) == SAMPLES:
            arrived.set()

    deliver_samples(on_sample, arrived, seen)
    threads = {thread for thread, _ in seen}
    assert threading.get_ident() not in threads
    counts = [count for _, count in seen]
    assert counts == list(range(counts[0], counts[0] + SAMPLES)), counts


@pytest.mark.skipif(not hasattr(os, "SCHED_BATCH"), reason="SCHED_BATCH is Linux's")
def test_the_network_thread_runs_as_sched_batch_and_the_opening_thread_keeps_its_policy() -> None:
    """Zenoh's thread, which runs every callback, was started as SCHED_BATCH (so a packet or a put
    that wakes it never preempts the Python thread on its core); the thread that opened the sessions
    runs under the policy it had."""
    policy = os.sched_getscheduler(0)
    seen: list[int] = []  # the scheduling policy of the thread running each callback
    arrived = threading.Event()

    def on_sample(sample: object) -> None:
        seen.append(os.sched_getscheduler(0))
        if len(seen) == SAMPLES:
            arrived.set()

    deliver_samples(on_sample, arrived, seen)
    assert seen == [os.SCHED_BATCH] * SAMPLES
    assert os.sched_getscheduler(0) == policy != os.SCHED_BATCH
