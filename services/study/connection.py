"""One participant's connection to the study server: their socket, its input read in the
background (services/human/core.py Controls), its output through an outbox, and the waits a
visit makes on it (a message of a kind, the socket's end)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable

import websockets
from websockets.asyncio.server import ServerConnection
from websockets.protocol import State

from services.human.core import BadInput, Controls
from services.human.gateway import Outbox
from shared.page import Answer, Keys, PageMessage

READ_TIMEOUT = 900.0  # seconds a participant may take to read the consent text or the instructions


class Socket:
    """One participant's connection: its input read in the background, its output through an outbox."""

    def __init__(self, ws: ServerConnection) -> None:
        self.ws = ws
        self.controls = Controls()
        self.outbox = Outbox(asyncio.get_running_loop())
        self.events: asyncio.Queue[str] = asyncio.Queue()
        self.gone = asyncio.Event()
        self.answer = ""  # the last answer to an attention check
        self.tasks = [asyncio.ensure_future(self._read()), asyncio.ensure_future(self._pump())]

    def send(self, message: PageMessage) -> None:
        self.outbox.offer(message.encode(), control=True)

    @property
    def closed(self) -> bool:
        """Whether the participant has gone, or is going: a close frame received counts at once,
        before the reader has seen the end."""
        return self.gone.is_set() or self.ws.state is not State.OPEN

    async def _read(self) -> None:
        try:
            async for text in self.ws:
                message = self.controls.receive(text, ("consent", "decline", "ready", "keys", "answer"))
                if isinstance(message, Answer):
                    self.answer = message.answer
                if message is not None and not isinstance(message, Keys):
                    self.events.put_nowait(message.TYPE)
        except BadInput as error:
            await self.ws.close(1008, str(error))
        except websockets.ConnectionClosed:
            pass
        finally:
            self.gone.set()

    async def _pump(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            await self.outbox.pump(self.ws)

    async def wait_for(self, kind: str | tuple[str, ...], timeout: float = READ_TIMEOUT) -> str:
        """Wait for the participant's `kind` message (or one of the kinds) and return its kind; ""
        if the socket closed first or it took longer than `timeout` seconds (the socket is then
        closed: an idle socket holds nothing)."""
        event: asyncio.Future | None = None
        try:
            async with asyncio.timeout(timeout):
                while True:
                    event = asyncio.ensure_future(self.events.get())
                    await first(event, self.gone.wait())
                    if not event.done():
                        return ""
                    if event.result() in ((kind,) if isinstance(kind, str) else kind):
                        return event.result()
        except TimeoutError:
            await self.ws.close(1008, "idle for too long")
            self.gone.set()
            return ""
        finally:
            if event is not None and not event.done():  # never a get left pending on the loop
                event.cancel()

    async def close(self) -> None:
        """Let the outbox empty (what was just offered is queued after one turn of the loop), then close."""
        await asyncio.sleep(0)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.outbox.flushed.wait(), 2.0)
        await self.ws.close()
        for task in self.tasks:
            task.cancel()


async def first(*waits: Awaitable) -> None:
    """Return when the first of `waits` is done; pending coroutines are cancelled, futures given
    are left running."""
    futures = [asyncio.ensure_future(w) for w in waits]
    try:
        await asyncio.wait(futures, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for wait, future in zip(waits, futures, strict=True):
            if future is not wait:
                future.cancel()
