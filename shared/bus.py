"""Opening zenoh sessions from one config, counting bad input, and stopping cleanly on signals.

Peer mode by default: no router is needed. Multicast scouting is off unless asked for, so that
parallel runs on one machine never meet; peers find each other through the explicit endpoints and
zenoh's gossip (a peer that connects to one learns the others).
"""

from __future__ import annotations

import json
import logging
import random
import re
import signal
import socket
import threading
import weakref
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypeVar

import zenoh

from shared import keys
from shared.errors import UsageError
from shared.messages import M, MatchOrder, MatchRefused, Summary, decode, printable

T = TypeVar("T")

log = logging.getLogger("tsf.bus")

MODES = ("peer", "client", "router")
ENDPOINT = re.compile(r"^[a-z][a-z0-9-]*/[^?#]")  # <protocol>/<address>[?<metadata>][#<config>]


@dataclass(frozen=True)
class BusConfig:
    """Where a service's session listens and connects. Endpoints are zenoh locators such as
    `tcp/127.0.0.1:7447`; `tcp/127.0.0.1:0` listens on a free loopback port."""

    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    multicast: bool = False
    low_latency: bool = False  # zenoh's low-latency unicast transport (no QoS); every peer must agree
    user: str = ""  # credentials for a secured router (shared/router.py); empty: none
    password: str = ""
    wait_router: float = 10.0  # seconds a client keeps trying to reach its router at start

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise UsageError("--mode", self.mode, "unknown zenoh mode", MODES)
        for option, endpoints in (("--listen", self.listen), ("--connect", self.connect)):
            for endpoint in endpoints:
                if not ENDPOINT.match(endpoint):
                    raise UsageError(option, endpoint, "not a zenoh endpoint such as tcp/127.0.0.1:7447")

    def to_zenoh(self) -> zenoh.Config:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps(self.mode))
        config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        config.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast))
        # Of two peers that learn of each other by gossip, only one dials: when both did at once, the
        # low-latency transport sometimes kept neither link, and peers do not relay for each other.
        strategy = {"peer": {"to_router": "always", "to_peer": "greater-zid"}}
        config.insert_json5("scouting/gossip/autoconnect_strategy", json.dumps(strategy))
        # A client waits for its router (services may start in any order); a peer retries in the
        # background for ever (zenoh's default).
        timeouts = {"client": round(self.wait_router * 1000), "peer": -1, "router": -1}
        config.insert_json5("connect/timeout_ms", json.dumps(timeouts))
        # Retry soon and often (zenoh: from 1 s up to 4 s): a match's clients start together with
        # its sim, and each second of back-off would delay its first frame.
        retry = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
        config.insert_json5("connect/retry", json.dumps(retry))
        if self.user:
            config.insert_json5(
                "transport/auth/usrpwd", json.dumps({"user": self.user, "password": self.password})
            )
        if self.low_latency:
            config.insert_json5("transport/unicast/lowlatency", "true")
            config.insert_json5("transport/unicast/qos/enabled", "false")
        return config

    def to_args(self) -> list[str]:
        """The same config as `tsf` options, for starting a service in another process."""
        args = ["--mode", self.mode]
        for endpoint in self.listen:
            args += ["--listen", endpoint]
        for endpoint in self.connect:
            args += ["--connect", endpoint]
        args += ["--multicast"] if self.multicast else []
        args += ["--user", self.user] if self.user else []
        args += ["--wait-router", str(self.wait_router)] if self.mode == "client" else []
        return [*args, "--low-latency"] if self.low_latency else args


_ports = random.Random()  # its own generator: a test that seeds the global one must not pick our ports


def free_endpoint(host: str = "127.0.0.1") -> str:
    """A TCP endpoint on a port that is free now (for the sim a local match connects to).

    The port is drawn below the kernel's ephemeral range where there is one: between this check and
    the listener's bind, an outgoing connection (which takes its port from that range) or another
    bind to port 0 could take a port from inside it, and the listener then fails with "Address
    already in use". Elsewhere, the kernel picks."""
    low = ephemeral_low()
    for _ in range(64 if low > 11024 else 0):
        port = _ports.randrange(10000, low)
        with socket.socket() as sock:
            try:
                sock.bind((host, port))
            except OSError:
                continue
            return f"tcp/{host}:{port}"
    with socket.socket() as sock:
        sock.bind((host, 0))
        return f"tcp/{host}:{sock.getsockname()[1]}"


def ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range, or 0 where it can't be read (not Linux)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 0


def why(error: zenoh.ZError) -> str:
    """zenoh's error text without the source location it ends with (for a user's one line)."""
    return str(error).split(" at /", 1)[0]


@contextmanager
def session(config: BusConfig) -> Iterator[zenoh.Session]:
    """An open zenoh session, closed on exit (an unclosed session keeps the process alive)."""
    opened = zenoh.open(config.to_zenoh())
    try:
        yield opened
    finally:
        opened.close()


class Drops:
    """Counts dropped input by reason and logs each reason once, so bad input never floods logs."""

    def __init__(self, service: str) -> None:
        self.service = service
        self.counts: Counter[str] = Counter()
        self._lock = threading.Lock()

    def drop(self, key: str, error: Exception) -> None:
        reason = getattr(error, "reason", type(error).__name__)
        with self._lock:
            self.counts[reason] += 1
            first = self.counts[reason] == 1
        if first:
            log.warning(
                "%s dropped input on %s (%s); further drops of this kind are only counted",
                self.service,
                key,
                error,
            )

    @property
    def total(self) -> int:
        return sum(self.counts.values())


Decoder = Callable[[bytes, str], M]  # (payload, key) -> a valid message, or MessageError


def subscribe(
    z: zenoh.Session,
    key: str,
    kind: type[M] | Decoder[M],
    handler: Callable[[M], None],
    drops: Drops | None = None,
) -> zenoh.Subscriber:
    """Subscribe `handler` to the valid messages on `key`. Decoding and validation happen here, once:
    `kind` is the message type, or a decoder that also reads the key (decode_seat_action). Input that
    fails, or that the handler refuses by raising ValueError (MessageError for a contract reason), is
    counted in `drops` by reason and dropped. A handler's put that finds the session closed (a
    sample still in flight while the service ends) is let go. Use the subscriber as a context
    manager to undeclare it (publishers that callbacks use are left to the session's close:
    undeclaring one mid-put fails)."""

    def on_sample(sample: zenoh.Sample) -> None:
        where = str(sample.key_expr)
        try:
            data = sample.payload.to_bytes()
            handler(decode(data, kind) if isinstance(kind, type) else kind(data, where))
        except ValueError as error:
            if drops is not None:
                drops.drop(where, error)
        except zenoh.ZError:  # a late sample whose answer meets the session closed: the service is ending
            if not z.is_closed():
                raise

    return z.declare_subscriber(key, on_sample)


def on_match_end(z: zenoh.Session, match: str, ended: threading.Event, drops: Drops) -> ExitStack:
    """Set `ended` when the match is over for a service that plays a part of it: its valid summary
    arrives, or the sim's token goes away (a killed sim publishes none). A sim not seen yet ends
    nothing: a part may be ready before its sim. Close the stack to undeclare both subscribers."""

    def on_sim(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            ended.set()

    watches = ExitStack()
    watches.enter_context(subscribe(z, keys.summary(match), Summary, lambda _: ended.set(), drops))
    watches.enter_context(z.liveliness().declare_subscriber(keys.alive(match, "sim"), on_sim, history=True))
    return watches


class Part(Protocol):
    """A service's part in one match (its subscriptions, publishers and token, declared when made):
    `ended` is set when the match is over for it (on_match_end), `close` undeclares everything."""

    match: str
    ended: threading.Event

    def close(self) -> None: ...


P = TypeVar("P", bound=Part)
ORDERS_KEPT = 4096  # match ids a pool service remembers, so that a re-put order is ignored


class Seen:
    """The last ORDERS_KEPT match ids a pool service was ordered (or stopped), oldest forgotten
    first: the launcher re-puts an order until the match's tokens are up, and a pool runs for hours."""

    def __init__(self, size: int = ORDERS_KEPT) -> None:
        self.size, self.ids = size, OrderedDict[str, None]()

    def add(self, match: str) -> bool:
        """Remember `match`; whether it is new."""
        if match in self.ids:
            return False
        self.ids[match] = None
        if len(self.ids) > self.size:
            self.ids.popitem(last=False)
        return True


def serve_orders(
    z: zenoh.Session,
    pool: str,
    service: str,
    start: Callable[[MatchOrder], list[P]],
    drops: Drops,
    stop: threading.Event,
    every: float = 0.5,
    tick: Callable[[list[P]], None] = lambda parts: None,
    wake: threading.Event | None = None,
) -> None:
    """Play the matches a pool's orders name until `stop` is set, then close every part still open.
    Each order's match gets the parts `start` makes (none: the service plays no part in it; a
    ValueError: the order is counted as a drop, and refused at once, `refuse_order`; any other
    error is logged with its traceback and refused too). The launcher re-puts an order until it
    sees the match's tokens, so the last ORDERS_KEPT ids are remembered and an order of one of
    them is ignored, a bad one's included. Once `every` seconds, and at once
    whenever a part sets `wake`, this thread closes the parts that ended and calls `tick` with the
    others (zenoh's callback threads never undeclare). The pool's token is declared once the order
    key is subscribed."""
    seen = Seen()
    parts: list[P] = []
    lock = threading.Lock()

    def on_order(order: MatchOrder) -> None:
        with lock:
            if not seen.add(order.match):
                return
        try:
            made = start(order)
        except ValueError as error:
            drops.drop(keys.pool_order(pool), error)
            refuse_order(z, pool, service, order, error)
            return
        except Exception as error:  # our fault, not the order's: logged whole, and refused all the same
            log.exception("%s could not start match %s", service, order.match)
            refuse_order(z, pool, service, order, error)
            return
        with lock:
            parts.extend(made)

    try:
        with (
            subscribe(z, keys.pool_order(pool), MatchOrder, on_order, drops),
            z.liveliness().declare_token(keys.pool_alive(pool, service)),
        ):
            while not woken(stop, wake, every):
                with lock:
                    ended = [part for part in parts if part.ended.is_set()]
                    parts[:] = [part for part in parts if not part.ended.is_set()]
                    live = list(parts)
                for part in ended:
                    part.close()
                tick(live)
    finally:  # orders no longer arrive
        with lock:
            left, parts[:] = list(parts), []
        for part in left:
            part.close()


def refuse_order(z: zenoh.Session, pool: str, service: str, order: MatchOrder, error: Exception) -> None:
    """Say at once, on tsf/pool/<pool>/refused, that `service` cannot play its part of `order`
    (`error` its reason): the launcher fails the match now. Silent, the order's launcher waited for
    a token that never came (two 30-s waits), and a study's participant three attempts (302 s)."""
    refusal = MatchRefused(
        match=order.match, frame=0, sender=service, service=service, reason=printable(str(error), 300)
    )
    z.put(keys.pool_refused(pool), refusal.encode())


def woken(stop: threading.Event, wake: threading.Event | None, most: float) -> bool:
    """Wait up to `most` seconds for `wake` (cleared as it returns, so that a part that sets it
    while the caller works wakes the next wait), or for `stop` where there is no `wake`; whether
    `stop` is set."""
    if wake is None:
        return stop.wait(most)
    wake.wait(most)
    wake.clear()
    return stop.is_set()


def weakly(method: Callable[[T], None]) -> Callable[[T], None]:
    """A bound method as a bus callback that does not keep its object alive: zenoh-python (1.10)
    may keep a callback for a while after its subscriber is undeclared (a liveliness
    subscriber's), and a long-lived service that subscribes per match (a pool's) must not keep an
    ended match with it. Only this small function stays."""
    ref = weakref.WeakMethod(method)

    def call(arg: T) -> None:
        bound = ref()
        if bound is not None:
            bound(arg)

    return call


def until_stopped(stop: threading.Event) -> None:
    """Wait until `stop` is set, waking twice a second. A signal the kernel hands to another thread
    (zenoh's own) only sets a flag: Python runs the handler in the main thread when it next wakes,
    and a wait without end never did (a Ctrl-C of `tsf study` was lost)."""
    while not stop.wait(0.5):
        pass


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT, SIGTERM or SIGHUP (Ctrl-C, `timeout` or a scheduler, a closed
    terminal or a supervisor): services poll it and leave through their `finally`, launchers end
    their children."""
    stop = threading.Event()

    def on_signal(*_: object) -> None:
        # The handler runs in the main thread, which may hold the event's lock inside stop.wait():
        # a launcher that dies sends SIGTERM just as the match's summary sets the event. Setting it
        # here would wait for that lock forever (an agent was left running); a thread sets it.
        if not stop.is_set():
            threading.Thread(target=stop.set, daemon=True).start()

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, on_signal)
    return stop
