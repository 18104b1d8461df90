"""The human gateway's shell: a web server for the one page, a WebSocket per player, and the bus.

One thread runs the asyncio web server (websockets); zenoh's callbacks run on zenoh's threads. A
State from the sim is answered at once, on zenoh's thread, with the seat's latest key state (so the
sim stays the clock and a slow browser never delays an action), and handed to the connection as
the newest frame to draw: a browser that falls behind skips frames, it never queues them. The
seat's liveliness token is declared once the person is ready and goes when the socket closes, so
a dropped connection leaves the ship idle (the sim plays no-op) and the match goes on. A
spectator's connection (`watch`) gets the same frames and plays no seat: it never publishes and
holds no token, so anyone may watch a match or its live replay (`tsf replay --live`).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import mimetypes
import ssl
import threading
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import websockets
import zenoh
from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from services.human.core import (
    NO_ROUND_ENDING,
    BadInput,
    Controls,
    Narrator,
    SeatBook,
    end,
    event_view,
    parse,
    points,
    setup,
    view,
)
from shared import keys
from shared.bus import BusConfig, Drops, session, subscribe, until_stopped
from shared.game import HUMAN, GameConfig
from shared.messages import Action, GameEvent, Message, MessageError, Start, State, Summary
from shared.page import MAX_MESSAGE, Join, PageMessage, Ready, Refused, Setup, Welcome

log = logging.getLogger("tsf.human")
STATIC = Path(__file__).parent / "static"
PAGES = {"/": "index.html", "/index.html": "index.html", "/tsf.js": "tsf.js", "/contract.js": "contract.js"}
SOCKET_PATH = "/ws"
JOIN_TIMEOUT = 60.0  # seconds a new socket has to say who it is
REFUSED = 4003  # WebSocket close code: seat refused
CLOSE_TIMEOUT = 1.0  # seconds a closing connection gets to answer (a browser that never does holds exit)
OPEN_TIMEOUT = 10.0  # seconds a new connection has to finish its HTTP request or WebSocket handshake
# The page loads its own script and talks to its own server; nothing else, and no one may frame it.
HEADERS = (
    (
        "Content-Security-Policy",
        "default-src 'none'; script-src 'self'; style-src 'unsafe-inline'; connect-src 'self'; "
        "img-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    ),
    ("X-Frame-Options", "DENY"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
    ("Cache-Control", "no-store"),
)


@dataclass(frozen=True)
class Web:
    """How the page is served. `cert`/`key` (PEM files) turn on TLS; `origins` are further origins
    (`https://study.example.org`) whose pages may open the socket besides the server's own (the
    Host the browser asked for), and whose host names requests may ask for (`known_host`);
    `per_address` caps the sockets one address holds at once (0: no cap; behind a reverse proxy
    every client has the proxy's address, so let the proxy cap them)."""

    host: str = "127.0.0.1"
    port: int = 8000
    cert: Path | None = None
    key: Path | None = None
    origins: tuple[str, ...] = ()
    per_address: int = 8

    def tls(self) -> ssl.SSLContext | None:
        if self.cert is None:
            return None
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        context.load_cert_chain(self.cert, self.key)
        return context


class Outbox:
    """What goes down one socket: control messages in order, and only the newest frame (after the
    control messages offered with it: a frame after the match's end is harmless, one before its
    set-up would be drawn with the wrong numbers)."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.frame: str | None = None
        self.control: list[str] = []
        self.wake = asyncio.Event()
        self.flushed = asyncio.Event()  # set while everything offered has been sent
        self.flushed.set()

    def offer(self, text: str, control: bool = False) -> None:
        """From any thread."""
        self.loop.call_soon_threadsafe(self._put, text, control)

    def _put(self, text: str, control: bool) -> None:
        if control:
            self.control.append(text)
        else:
            self.frame = text
        self.flushed.clear()
        self.wake.set()

    async def pump(self, ws: ServerConnection) -> None:
        """Send until the socket closes."""
        while True:
            await self.wake.wait()
            self.wake.clear()
            frame, self.frame = self.frame, None
            control, self.control = self.control, []
            for text in control + ([frame] if frame else []):  # set-up before the frame it draws
                await ws.send(text)
            if not self.wake.is_set():
                self.flushed.set()


class Bridge:
    """One seat of one match on the bus, for one connection: answers each state with the held keys
    (once the person is ready), forwards frames (narrated for the seat), the events the page shows
    and the result down, holds the seat's token. With no role it only forwards (a spectator)."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        role: str | None,
        controls: Controls,
        outbox: Outbox,
        obs: bool = False,
    ) -> None:
        self.z, self.match, self.role, self.controls, self.outbox = z, match, role, controls, outbox
        self.obs = obs  # also send the seat's observation values (for scripted stand-ins)
        self.sender = f"human/{role or 'watch'}"
        self.drops = Drops(self.sender)
        self.config = GameConfig()
        self.narrator = Narrator(role, False, self.config.respawn_delay)
        self.summary = threading.Event()
        self.declared = contextlib.ExitStack()  # everything below, undeclared together by close()
        declare = self.declared.enter_context
        self.token: zenoh.LivelinessToken | None = None
        self.publisher = role and declare(
            z.declare_publisher(
                keys.action(match, role), congestion_control=zenoh.CongestionControl.DROP, express=True
            )
        )
        declare(subscribe(z, keys.state(match), State, self._on_state, self.drops))
        declare(subscribe(z, keys.start(match), Start, self._on_start, self.drops))
        declare(subscribe(z, keys.summary(match), Summary, self._on_summary, self.drops))
        declare(subscribe(z, keys.event(match), GameEvent, self._on_event, self.drops))

    def live(self) -> None:
        """The person is ready: take the seat on the bus (the sim waits for it)."""
        if self.token is None and self.role is not None:
            token = self.z.liveliness().declare_token(keys.alive(self.match, "human", self.role))
            self.token = self.declared.enter_context(token)

    def _check(self, message: Message) -> None:
        if message.match != self.match:
            raise MessageError("mismatch", f"{message.TYPE} of {message.match} in match {self.match}")

    def _on_state(self, state: State) -> None:
        self._check(state)
        if self.token is not None and not state.last:
            action = Action(
                match=self.match,
                frame=state.frame,
                sender=self.sender,
                role=self.role,
                action=self.controls.action,
                policy="",
            )
            self.publisher.put(action.encode())
        self.outbox.offer(view(state, self.narrator(state), self.obs, self.role).encode())

    def _on_start(self, start: Start) -> None:
        self._check(start)
        self.config = GameConfig.from_dict(start.config)
        partner = next((p for r, p in start.policies.items() if r != self.role), HUMAN)
        ends = self.role is not None and partner not in (HUMAN, *NO_ROUND_ENDING)
        self.narrator = Narrator(self.role, ends, self.config.respawn_delay)
        self.outbox.offer(Setup(**setup(self.config)).encode(), control=True)

    def _on_event(self, event: GameEvent) -> None:
        self._check(event)
        shown = event_view(event)
        if shown is not None:
            self.outbox.offer(shown.encode(), control=True)

    def _on_summary(self, summary: Summary) -> None:
        self._check(summary)
        self.outbox.offer(end(summary, self.config.frames).encode(), control=True)
        self.summary.set()

    def close(self) -> None:
        self.declared.close()
        self.token = None


async def play_seat(ws: ServerConnection, bridge: Bridge, outbox: Outbox) -> None:
    """Pump frames down and take keys up until the socket closes; the connection is closed if it
    keeps sending bad or excess input."""
    pump = asyncio.ensure_future(outbox.pump(ws))
    try:
        async for text in ws:
            try:
                message = bridge.controls.receive(text)
            except BadInput as error:
                await ws.close(1008, str(error))
                break
            if isinstance(message, Ready):
                bridge.live()
    finally:
        pump.cancel()
        with contextlib.suppress(asyncio.CancelledError, websockets.ConnectionClosed):
            await pump


async def receive_first(ws: ServerConnection, allowed: tuple[str, ...]) -> PageMessage | None:
    """The socket's first message, validated; None (and the socket closed) if it is bad or late."""
    try:
        text = await asyncio.wait_for(ws.recv(), JOIN_TIMEOUT)
        return parse(text, allowed)
    except (BadInput, TimeoutError) as error:
        await ws.close(1008, str(error)[:120])
    except websockets.ConnectionClosed:
        pass
    return None


async def refuse(ws: ServerConnection, reason: str) -> None:
    """Say why and close; a client that has gone already is simply gone (no traceback)."""
    with contextlib.suppress(websockets.ConnectionClosed):
        await ws.send(Refused(reason=reason).encode())
        await ws.close(REFUSED, reason[:120])


def serve_page(
    connection: ServerConnection, request: Request, pages: dict[str, str] = PAGES
) -> Response | None:
    """Plain HTTP for the `pages` (path -> file in static/); the socket path goes on to the
    WebSocket handshake."""
    path = request.path.split("?", 1)[0]
    if path == SOCKET_PATH:
        return None
    name = pages.get(path)
    if name is None:
        return connection.respond(404, "not found\n")
    body = (STATIC / name).read_bytes()
    kind = mimetypes.guess_type(name)[0] or "application/octet-stream"
    headers = Headers(
        [("Content-Type", f"{kind}; charset=utf-8"), ("Content-Length", str(len(body))), *HEADERS]
    )
    return Response(200, "OK", headers, body)


SINGLE = ("Host", "Origin")  # headers a request may carry once: two are refused with 400


def duplicated(request: Request) -> bool:
    """Whether the request carries a header of SINGLE more than once (which one counts would be a
    guess, and websockets' own reading of it fails)."""
    return any(len(request.headers.get_all(name)) > 1 for name in SINGLE)


def same_origin(request: Request, allowed: tuple[str, ...], scheme: str = "http") -> bool:
    """A browser's socket comes from the server's own page (Origin is `scheme`://the Host it asked
    for, so a page over plain HTTP cannot drive a TLS server's socket nor the other way round) or
    from an allowed origin; a client that sends no Origin is no browser, and no web page drives it."""
    origin = request.headers.get("Origin")
    if origin is None or origin in allowed:
        return True
    parts = urlsplit(origin)
    return parts.scheme == scheme and parts.netloc == request.headers.get("Host")


def known_host(request: Request, web: Web) -> bool:
    """Whether the Host the browser asked for is this server's. Against DNS rebinding: a page of
    evil.example whose name is then pointed at this server's address sends Host and Origin both
    evil.example, which the Origin check alone takes for the server's own page. Taken: an address
    (an IP literal, or localhost, which browsers resolve themselves: no one can re-point them), the
    name the server listens on, or an allowed origin's (`--origin`, a reverse proxy's public name)."""
    host = request.headers.get("Host")
    if host is None:
        return False
    name = (urlsplit(f"//{host}").hostname or "").lower()
    with contextlib.suppress(ValueError):
        ipaddress.ip_address(name)
        return True
    allowed = {urlsplit(origin).netloc.lower() for origin in web.origins}
    return name in ("localhost", web.host.lower()) or host.lower() in allowed


Handler = Callable[[ServerConnection, zenoh.Session | None], Awaitable[None]]


class Gateway:
    """The web server and one zenoh session, running in a thread of their own until closed.

    `handler(ws, z)` serves one socket. The session listens where `bus` says, so that a match's sim
    can connect to it (MatchPlan.peers); with no `bus` there is none (z is None): the study server
    opens a session per trial instead, to that match's sim alone. Served as `web` says: TLS, the
    Host and Origin checks, a cap on sockets per address, no version banner; `pages` are the files it
    serves."""

    def __init__(
        self, bus: BusConfig | None, handler: Handler, web: Web = Web(), pages: dict[str, str] = PAGES
    ) -> None:
        self.bus, self.handler, self.web, self.pages = bus, handler, web, pages
        self.port = web.port
        self.loop = asyncio.new_event_loop()
        self.ready = threading.Event()
        self.failed: BaseException | None = None
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(self._run(),), daemon=True)
        self.closing: asyncio.Future | None = None
        self.sockets: Counter[str] = Counter()  # open sockets per address
        self.misdirected = False  # a request for another host has been logged

    @property
    def url(self) -> str:
        return f"{'https' if self.web.cert else 'http'}://{self.web.host}:{self.port}/"

    def __enter__(self) -> Gateway:
        self.thread.start()
        self.ready.wait()
        if self.failed is not None:
            raise self.failed
        return self

    def __exit__(self, *exc: object) -> None:
        if self.closing is not None:
            self.loop.call_soon_threadsafe(self.closing.set_result, None)
        self.thread.join(10)
        if not self.thread.is_alive():
            self.loop.close()

    def _request(self, connection: ServerConnection, request: Request) -> Response | None:
        if duplicated(request):
            return connection.respond(400, "bad request\n")
        if not known_host(request, self.web):
            if not self.misdirected:
                self.misdirected = True
                log.warning(
                    "refused a request for host %r (and say so once): not this server's name; a "
                    "public name goes in --origin", request.headers.get("Host", "")[:80],
                )  # fmt: skip
            return connection.respond(421, "misdirected request\n")
        if request.path.split("?", 1)[0] == SOCKET_PATH:
            if not same_origin(request, self.web.origins, "https" if self.web.cert else "http"):
                return connection.respond(403, "forbidden\n")
            if self.web.per_address and self.sockets[connection.remote_address[0]] >= self.web.per_address:
                return connection.respond(429, "too many connections\n")
        return serve_page(connection, request, self.pages)

    async def _handle(self, ws: ServerConnection, z: zenoh.Session | None) -> None:
        address = ws.remote_address[0]
        self.sockets[address] += 1
        try:
            await self.handler(ws, z)
        finally:
            self.sockets[address] -= 1
            if not self.sockets[address]:
                del self.sockets[address]

    async def _run(self) -> None:
        try:
            with session(self.bus) if self.bus else contextlib.nullcontext() as z:
                self.closing = self.loop.create_future()
                server = await serve(
                    lambda ws: self._handle(ws, z),
                    self.web.host, self.web.port, process_request=self._request, max_size=MAX_MESSAGE,
                    close_timeout=CLOSE_TIMEOUT, open_timeout=OPEN_TIMEOUT, ssl=self.web.tls(),
                    server_header=None,
                )  # fmt: skip
                self.port = server.sockets[0].getsockname()[1]
                self.ready.set()
                async with server:
                    await self.closing
                    server.close(close_connections=True)
        except BaseException as error:  # surfaced to the thread that opened the gateway
            self.failed = error
            raise
        finally:
            self.ready.set()


def seat_handler(match: str, book: SeatBook, done: threading.Event | None = None) -> Handler:
    """Serve the seats of one match: each socket joins one seat by its token and plays it, or
    watches."""

    async def handle(ws: ServerConnection, z: zenoh.Session) -> None:
        join = await receive_first(ws, ("join", "watch"))
        if join is None:
            return
        if not isinstance(join, Join):
            await watch(ws, z, match)
            return
        reason = book.claim(join.role, join.token, ws)
        if reason:
            log.info("refused a connection for %s: %s", join.role, reason)
            await refuse(ws, reason)
            return
        outbox, role = Outbox(asyncio.get_running_loop()), join.role
        bridge = Bridge(z, match, role, Controls(), outbox, bool(join.obs))
        try:
            welcome = Welcome(match=match, role=role, **setup(bridge.config), points=points(bridge.config))
            await ws.send(welcome.encode())
            log.info("a person took the %s seat of %s", role, match)
            await play_seat(ws, bridge, outbox)
        except websockets.ConnectionClosed:
            pass
        finally:
            bridge.close()
            book.release(role, ws)
            log.info("the %s seat of %s is free again", role, match)
            if done is not None and bridge.summary.is_set():
                done.set()

    return handle


async def watch(ws: ServerConnection, z: zenoh.Session, match: str) -> None:
    """A spectator: the match's frames and result go down, nothing goes on the bus."""
    outbox = Outbox(asyncio.get_running_loop())
    bridge = Bridge(z, match, None, Controls(), outbox)
    try:
        await ws.send(
            Welcome(match=match, role=None, **setup(bridge.config), points=points(bridge.config)).encode()
        )
        await play_seat(ws, bridge, outbox)
    except websockets.ConnectionClosed:
        pass
    finally:
        bridge.close()


def run_human(
    bus: BusConfig,
    match: str,
    tokens: dict[str, str],
    host: str = "127.0.0.1",
    port: int = 8000,
    stop: threading.Event | None = None,
    on_ready: Callable[[Gateway], None] = lambda gateway: None,
) -> None:
    """The `tsf human` service: serve the page and the seats of `match` that have tokens, until a
    player has seen the match end and left, or `stop` is set."""
    stop = stop or threading.Event()
    with Gateway(bus, seat_handler(match, SeatBook(tokens), stop), Web(host, port)) as gateway:
        on_ready(gateway)
        until_stopped(stop)
