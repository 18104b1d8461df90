"""The bus helpers that need no session."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
import weakref
from pathlib import Path

from shared.bus import ephemeral_low, free_endpoint, weakly, woken

ROOT = Path(__file__).parent.parent

# A launcher that dies sends SIGTERM to its services just as the sim's summary sets their stop
# event: the handler then runs while the main thread holds the event's lock inside stop.wait().
HOLDING_THE_LOCK = """
import os, signal
from shared.bus import stop_on_signals
stop = stop_on_signals()
with stop._cond:  # where Event.wait holds it
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(1000))  # the handler runs here
print(stop.wait(10))
"""


def test_a_signal_sets_the_stop_event_even_while_the_main_thread_holds_its_lock() -> None:
    done = subprocess.run(
        [sys.executable, "-c", HOLDING_THE_LOCK], cwd=ROOT, capture_output=True, text=True, timeout=20
    )
    assert done.stdout.strip() == "True", done.stderr


def test_a_weak_callback_calls_its_object_while_it_lives_and_keeps_it_not() -> None:
    class Match:
        def __init__(self) -> None:
            self.seen: list[int] = []

        def on(self, value: int) -> None:
            self.seen.append(value)

    match = Match()
    callback = weakly(match.on)
    callback(1)
    assert match.seen == [1]
    kept = weakref.ref(match)
    del match
    assert kept() is None  # the callback alone does not keep it
    callback(2)  # a late sample: nothing to call


def test_a_pool_service_remembers_the_last_orders_it_saw_and_forgets_the_oldest() -> None:
    from shared.bus import Seen

    seen = Seen(2)
    assert [seen.add(m) for m in ("a", "b", "a", "c")] == [True, True, False, True]
    assert seen.add("a") and not seen.add("c"), "a, the oldest, was forgotten; c is still known"


def test_a_free_endpoint_lies_below_the_ephemeral_range_where_no_outgoing_connection_takes_it() -> None:
    low = ephemeral_low()
    for _ in range(20):
        endpoint = free_endpoint()
        host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
        with socket.socket() as sock:
            sock.bind((host, int(port)))  # still free
        assert int(port) < low or low <= 11024, endpoint


def test_woken_returns_at_once_when_woken_and_clears_the_wake() -> None:
    stop, wake = threading.Event(), threading.Event()
    wake.set()
    began = time.monotonic()
    assert not woken(stop, wake, 10.0) and not wake.is_set()
    assert time.monotonic() - began < 1.0
    stop.set()
    assert woken(stop, wake, 0.01) and woken(stop, None, 10.0)  # stop reads at once without a wake
