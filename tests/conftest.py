"""Shared fixtures of the bus tests: one loopback endpoint per test, sessions and services that are
always closed or killed at teardown, a poll helper, and a tap that records what a match puts on the bus."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import ExitStack

import pytest
import zenoh

from services.runtime.launch import service_command
from shared import keys
from shared.bus import BusConfig, free_endpoint, session
from shared.messages import Message, MessageError, decode_any

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")  # Debian's, never a download


@pytest.fixture(scope="module")
def browser():  # noqa: ANN201 - a Playwright browser
    """Debian's Chromium, headless, for the tests of the web pages."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as playwright:
        launched = playwright.chromium.launch(
            executable_path=CHROMIUM, args=["--no-sandbox", "--disable-background-networking"]
        )
        yield launched
        launched.close()


def wait_until(predicate: Callable[[], object], timeout: float = 5.0, interval: float = 0.005) -> bool:
    """Poll `predicate` until it is true or `timeout` seconds pass; returns its last truth."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return bool(predicate())
        time.sleep(interval)
    return True


class Bus:
    """The test's bus: one free loopback endpoint that one session listens on and the others connect
    to (multicast off). Sessions opened here are closed at teardown."""

    def __init__(self, endpoint: str, stack: ExitStack, low_latency: bool = False) -> None:
        self.endpoint, self._stack = endpoint, stack
        self.low_latency = low_latency  # zenoh's low-latency transport: every peer must agree

    def config(self, listen: bool = False) -> BusConfig:
        ends = {"listen": (self.endpoint,)} if listen else {"connect": (self.endpoint,)}
        return BusConfig(**ends, low_latency=self.low_latency)

    def open(self, listen: bool = False) -> zenoh.Session:
        return self._stack.enter_context(session(self.config(listen)))


class Tap:
    """Records every sample of a match in arrival order, decoded where valid, and the live tokens."""

    def __init__(self, z: zenoh.Session, match: str) -> None:
        self.match = match
        self.samples: list[tuple[float, str, Message | bytes]] = []  # (monotonic time, key, message)
        self.alive: set[str] = set()
        self._lock = threading.Lock()
        self._subscribers = [
            z.declare_subscriber(keys.everything(match), self._on_sample),
            z.liveliness().declare_subscriber(f"tsf/{match}/alive/**", self._on_alive, history=True),
        ]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        try:
            message: Message | bytes = decode_any(data)
        except MessageError:
            message = data
        with self._lock:
            self.samples.append((time.monotonic(), str(sample.key_expr), message))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        with self._lock:
            (self.alive.add if sample.kind == zenoh.SampleKind.PUT else self.alive.discard)(
                str(sample.key_expr)
            )

    def of(self, kind: type[Message], key: str | None = None) -> list:
        """The valid messages of one type (on one key, if given), in arrival order."""
        with self._lock:
            return [m for _, k, m in self.samples if isinstance(m, kind) and key in (None, k)]

    def timed(self, kind: type[Message]) -> list[tuple[float, Message]]:
        with self._lock:
            return [(t, m) for t, _, m in self.samples if isinstance(m, kind)]

    def is_alive(self, service: str, role: str | None = None) -> bool:
        with self._lock:
            return keys.alive(self.match, service, role) in self.alive

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()


@pytest.fixture
def endpoint() -> str:
    return free_endpoint()


@pytest.fixture
def bus(endpoint: str) -> Iterator[Bus]:
    with ExitStack() as stack:
        yield Bus(endpoint, stack)


@pytest.fixture(name="wait_until")
def wait_until_fixture() -> Callable[..., bool]:
    return wait_until


@pytest.fixture
def tap() -> Iterator[Callable[[zenoh.Session, str], Tap]]:
    taps: list[Tap] = []

    def make(z: zenoh.Session, match: str) -> Tap:
        taps.append(Tap(z, match))
        return taps[-1]

    yield make
    for made in taps:
        made.close()


@pytest.fixture
def background() -> Iterator[Callable[..., Future]]:
    """Runs a service function in a thread with `stop=` an event of its own (the future's `stop`, for a
    test that stops it early); all are set (and the threads joined) at teardown, so a failing test
    never leaves a service running."""
    stops: list[threading.Event] = []

    def start(fn: Callable[..., object], *args: object, **kwargs: object) -> Future:
        stops.append(threading.Event())
        future = pool.submit(fn, *args, stop=stops[-1], **kwargs)
        future.stop = stops[-1]  # type: ignore[attr-defined]
        return future

    with ThreadPoolExecutor(max_workers=16) as pool:
        yield start
        for stop in stops:
            stop.set()


@pytest.fixture
def spawn(tmp_path) -> Iterator[Callable[..., subprocess.Popen]]:  # noqa: ANN001 - pytest's tmp_path
    """Starts `tsf <service> <bus options> <args>` as a process (`python -m services.commands`, output to
    pytest's capture); every process still running at teardown is killed."""
    children: list[subprocess.Popen] = []

    def start(service: str, config: BusConfig, *args: str) -> subprocess.Popen:
        children.append(subprocess.Popen(service_command(service, config, *args), stdin=subprocess.DEVNULL))
        return children[-1]

    yield start
    for child in children:
        if child.poll() is None:
            child.kill()
        child.wait()


STAND_IN_TOKEN = "stand-in-token"  # the study server's test token: stand-ins showing it get observations


@pytest.fixture
def study_server() -> Iterator[Callable[..., tuple[threading.Event, str, Future]]]:
    """Start `run_study` in a thread: serve(config, directory, serving=..., web=...) -> (stop, url,
    future of the Study). Served on a free port, with STAND_IN_TOKEN as the test token by default;
    every server is stopped at teardown."""
    from services.human.gateway import Web
    from services.study.runner import run_study
    from services.study.serving import Serving

    stops: list[threading.Event] = []
    with ThreadPoolExecutor(4) as pool:

        def serve(config, directory, serving=None, web=None):  # noqa: ANN001, ANN202
            stop, urls = threading.Event(), []
            serving = serving or Serving(test_token=STAND_IN_TOKEN)
            server = pool.submit(
                run_study, config, directory, web or Web(port=0), stop, lambda g: urls.append(g.url), serving
            )
            stops.append(stop)
            assert wait_until(lambda: urls or server.done(), timeout=20), "the server starts"
            assert urls, server.exception()
            return stop, urls[0], server

        yield serve
        for stop in stops:
            stop.set()


def wait_in_page(page, expression: str, timeout: int) -> None:  # noqa: ANN001 - a Playwright Page
    """Poll `expression` in the page until true, within `timeout` ms. Playwright's wait_for_function
    compiles its predicate with the page's own eval, which the page's CSP forbids; evaluate does not."""
    deadline = time.monotonic() + timeout / 1000
    while not page.evaluate(expression):
        assert time.monotonic() < deadline, f"{expression} within {timeout} ms"
        page.wait_for_timeout(50)
