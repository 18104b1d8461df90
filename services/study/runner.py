"""`tsf study`: the study's front door on the human gateway. Each participant's socket stays open
across all their trials; each trial is a match of its own (services/launch.run_match: sim, agent,
adapter for adaptive variants, recorder), the participant's seat bridged from this process.

Study messages (down): `consent` (text), `participant` (id and resume key, kept by the browser),
`trial` (session, trial, role, the agent's label; what to read first), then the gateway's
`state`/`end` frames, and at last `done` (the end text) or `problem`. Up: `hello` (optionally
with the participant id and key to resume), `consent`, `ready`, `keys`.

Each trial's metadata goes into a sidecar `<match>.study.json` beside its recording, rather than
onto the bus: the participant id is nobody's business but the study's (bus traffic may cross a lab
network), no service needs it, and the contract stays as it is; the match id names study,
participant, session and trial too, so a recording alone still says where it belongs.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from collections.abc import Callable
from pathlib import Path

import websockets
import zenoh
from websockets.asyncio.server import ServerConnection

from services.human.core import BadInput, Controls
from services.human.gateway import Bridge, Gateway, Handler, Outbox, receive_first, refuse
from services.launch import HUMAN, MatchPlan, run_match
from services.study.core import Participant, Study, StudyConfig, Trial
from shared.bus import BusConfig, free_endpoint
from shared.game import other

log = logging.getLogger("tsf.study")
PROBLEM = "The game could not be started. Please tell the experimenter."


class Socket:
    """One participant's connection: its input read in the background, its output through an outbox."""

    def __init__(self, ws: ServerConnection) -> None:
        self.ws = ws
        self.controls = Controls()
        self.outbox = Outbox(asyncio.get_running_loop())
        self.events: asyncio.Queue[str] = asyncio.Queue()
        self.gone = asyncio.Event()
        self.tasks = [asyncio.ensure_future(self._read()), asyncio.ensure_future(self._pump())]

    def send(self, message: dict) -> None:
        self.outbox.offer(json.dumps(message), control=True)

    async def _read(self) -> None:
        try:
            async for text in self.ws:
                message = self.controls.receive(text, ("consent", "ready", "keys"))
                if message is not None and message["type"] != "keys":
                    self.events.put_nowait(message["type"])
        except BadInput as error:
            await self.ws.close(1008, str(error))
        except websockets.ConnectionClosed:
            pass
        finally:
            self.gone.set()

    async def _pump(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            await self.outbox.pump(self.ws)

    async def wait_for(self, kind: str) -> bool:
        """Wait for the participant's `kind` message; False if the socket closed first."""
        while True:
            event = asyncio.ensure_future(self.events.get())
            gone = asyncio.ensure_future(self.gone.wait())
            await asyncio.wait({event, gone}, return_when=asyncio.FIRST_COMPLETED)
            gone.cancel()
            if not event.done():
                event.cancel()
                return False
            if event.result() == kind:
                return True

    async def close(self) -> None:
        """Let the outbox empty (what was just offered is queued after one turn of the loop), then close."""
        await asyncio.sleep(0)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.outbox.flushed.wait(), 2.0)
        await self.ws.close()
        for task in self.tasks:
            task.cancel()


def study_handler(
    study: Study, endpoint: str, low_latency: bool = True, stop: threading.Event | None = None
) -> Handler:
    """Serve participants: consent or resume, then their trials one by one. `stop` ends a running
    trial's match and its processes (run_match)."""
    config = study.config
    recordings = study.directory / "recordings"
    playing: set[str] = set()

    async def admit(socket: Socket, hello: dict) -> Participant | None:
        if "participant" in hello:
            participant = study.resume(hello["participant"], hello.get("key", ""))
            if participant is None:
                await refuse(socket.ws, "unknown participant or resume key")
            return participant
        socket.send({"type": "consent", "text": config.consent})
        if not await socket.wait_for("consent"):
            return None
        participant = study.arrive()
        log.info("participant %s arrives and plays the %s", participant.id, participant.role)
        socket.send({"type": "participant", "participant": participant.id, "key": participant.key})
        return participant

    async def play(socket: Socket, z: zenoh.Session, trial: Trial, obs: bool) -> dict | None:
        """Run one trial with the participant in their seat; returns the sidecar, or None if the
        participant left (the match then runs out with their ship idle, and is marked dropped)."""
        seats = {trial.role: HUMAN, **trial.variant.plan(other(trial.role), trial.seed)}
        plan = MatchPlan(
            trial.match, trial.seed, config.frames, directory=recordings, peers=(endpoint,),
            low_latency=low_latency, **seats,
        )  # fmt: skip
        bridge = Bridge(z, trial.match, trial.role, socket.controls, socket.outbox, obs)
        bridge.live()
        study.record(trial, "running")
        running = asyncio.ensure_future(asyncio.to_thread(run_match, plan, stop=stop))
        gone = asyncio.ensure_future(socket.gone.wait())
        await asyncio.wait({running, gone}, return_when=asyncio.FIRST_COMPLETED)
        gone.cancel()
        bridge.close()

        dropped = not running.done()

        def finish(done: asyncio.Future) -> dict:
            failed = done.exception()
            if failed is not None:
                log.error("trial %s failed: %s", trial.match, failed)
            status = "failed" if failed else "dropped" if dropped else "done"
            kills = None if failed else done.result()[0].kills
            sidecar = study.record(trial, status, kills)
            recordings.mkdir(parents=True, exist_ok=True)
            (recordings / f"{trial.match}.study.json").write_text(json.dumps(sidecar, indent=1))
            log.info("%s: %s, %s kills", trial.match, status, kills)
            return sidecar

        if dropped:  # resumable at once; the sidecar follows when the match has run out
            study.record(trial, "dropped")
            running.add_done_callback(finish)
            return None
        return finish(running)

    async def handle(ws: ServerConnection, z: zenoh.Session) -> None:
        hello = await receive_first(ws, ("hello",))
        if hello is None:
            return
        socket = Socket(ws)
        participant = None
        try:
            participant = await admit(socket, hello)
            if participant is None:
                return
            if participant.id in playing:
                await refuse(ws, "this participant is already playing in another window")
                participant = None
                return
            playing.add(participant.id)
            last = None
            while (trial := study.next_trial(participant)) is not None:
                socket.send(
                    {
                        "type": "trial", "role": trial.role, "agent": trial.agent, "last": last,
                        "session": trial.session, "sessions": len(config.variants),
                        "trial": trial.trial, "trials": config.trials,
                        "instructions": config.instructions.get(trial.role, ""),
                    }
                )  # fmt: skip
                if not await socket.wait_for("ready"):
                    return
                sidecar = await play(socket, z, trial, hello.get("obs", False))
                if sidecar is None:
                    return
                if sidecar["status"] == "failed":
                    socket.send({"type": "problem", "text": PROBLEM})
                    await socket.close()
                    return
                last = sidecar["kills"]
            socket.send({"type": "done", "text": config.end})
            log.info("participant %s is done", participant.id)
            await socket.close()
        finally:
            if participant is not None:
                playing.discard(participant.id)
            for task in socket.tasks:
                task.cancel()

    return handle


def run_study(
    config: StudyConfig,
    directory: str | Path,
    host: str = "127.0.0.1",
    port: int = 8000,
    stop: threading.Event | None = None,
    on_ready: Callable[[Gateway], None] = lambda gateway: None,
    low_latency: bool = True,
) -> Study:
    """Serve the study until `stop` is set; participants' progress lives in `directory`."""
    stop = stop or threading.Event()
    study = Study(config, directory)
    endpoint = free_endpoint()
    bus = BusConfig(listen=(endpoint,), low_latency=low_latency)
    with Gateway(bus, study_handler(study, endpoint, low_latency, stop), host, port) as gateway:
        on_ready(gateway)
        stop.wait()
    return study
