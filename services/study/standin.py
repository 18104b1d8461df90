"""A headless stand-in participant: a policy that goes through the study as a person would, over the
same WebSocket protocol as the page (consent, ready, held keys), each message read and sent
through the page's contract (shared/page.py), so a whole study runs end to end
without anyone at a keyboard (tests, and dry runs of a new study config)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import websockets

from services.human.core import action_keys
from services.population.partners import make_partner
from services.sim.observation import as_observation
from services.sim.play import policy_seed
from shared.page import (
    Answer,
    Check,
    Consent,
    ConsentText,
    Done,
    End,
    Hello,
    ParticipantId,
    Problem,
    Queue,
    Ready,
    Refused,
    Screened,
    StateView,
    Stopped,
    Trial,
    Wait,
    decode_down,
)


@dataclass
class StandInReport:
    """What the stand-in went through."""

    participant: str = ""
    key: str = ""
    role: str = ""
    agents: list[str] = field(default_factory=list)  # the agent label of each trial started
    kills: list[int] = field(default_factory=list)  # each finished trial's kills
    cut: list[int] = field(default_factory=list)  # frames left in each trial stopped before its end
    states: int = 0
    consent: str = ""  # the consent text shown
    end: str = ""  # the end screen's text
    code: str = ""  # the completion code shown at the end
    redirect: str = ""  # where the page would go at the end (the platform's completion address)
    checks: int = 0  # attention checks asked
    screened: bool = False  # screened out (failed attention checks)
    done: bool = False
    refused: str = ""
    stopped: str = ""  # what the page says when the server stops (progress kept)
    queued: int = 0  # the furthest place in the queue it was shown
    first_frames: list[float] = field(default_factory=list)  # seconds from each Ready to its first frame
    waits: list[float] = field(default_factory=list)  # seconds each trial waited in the queue (if it did)
    # seconds to each trial's offer: the first from the consent, each next one from the trial's end before it
    offers: list[float] = field(default_factory=list)
    again: int = 0  # trials offered again after a failed attempt
    why: list[str] = field(default_factory=list)  # why each trial offered again is (the page says it)
    set_ups: int = 0  # `wait` messages: a game being set up, said before each trial


class _Visit:
    """What a stand-in holds between the server's messages: its report, the partner playing its
    role, the keys it holds, and its clocks. `on(message)` answers one message; True once the
    study is over for the stand-in (done, screened out, stopped, refused)."""

    def __init__(self, ws: object, policies: dict[str, str], seed: int, leave_after: int, attentive: bool):
        self.ws, self.policies, self.seed, self.leave_after, self.attentive = (
            ws, policies, seed, leave_after, attentive
        )  # fmt: skip
        self.report = StandInReport()
        self.policy, self.held, self.ready, self.queued, self.since = None, None, None, 0.0, time.monotonic()

    async def on(self, message: object) -> bool:
        if isinstance(message, StateView):
            return await self.frame(message)
        if isinstance(message, (ConsentText, ParticipantId, Check, Queue, Trial)):
            await self.before_game(message)
            return False
        report = self.report
        if isinstance(message, Wait):
            report.set_ups += 1
        elif isinstance(message, End):
            report.kills.append(message.kills)
            left = message.frames - message.frame
            report.cut += [left] if left > 0 else []
            self.since = time.monotonic()
        elif isinstance(message, Done):
            report.done, report.end, report.code = True, message.text, message.code
            report.redirect = message.redirect
        elif isinstance(message, Screened):
            report.screened, report.end, report.redirect = True, message.text, message.redirect
        elif isinstance(message, Stopped):
            report.stopped = message.text
        elif isinstance(message, (Refused, Problem)):
            report.refused = message.reason if isinstance(message, Refused) else message.text
        return isinstance(message, (Done, Screened, Stopped, Refused, Problem))

    async def before_game(self, message: object) -> None:
        """Consent, the participant's id, an attention check, the queue, a trial's offer."""
        report, ws = self.report, self.ws
        if isinstance(message, ConsentText):
            report.consent = message.text
            await ws.send(Consent().encode())
            self.since = time.monotonic()
        elif isinstance(message, ParticipantId):
            report.participant, report.key = message.participant, message.key
        elif isinstance(message, Check):
            report.checks += 1
            word = message.text.split('"')[1]  # the button the check names
            answer = word if self.attentive else next(o for o in message.options if o != word)
            await ws.send(Answer(answer=answer).encode())
        elif isinstance(message, Queue):
            report.queued = max(report.queued, message.place)
            self.queued = self.queued or time.monotonic()
        elif isinstance(message, Trial):
            await self.offered(message)

    async def offered(self, message: Trial) -> None:
        """A trial's offer: play it with the partner of the role, from Ready."""
        report = self.report
        report.offers.append(time.monotonic() - self.since)
        if self.queued:
            report.waits.append(time.monotonic() - self.queued)
            self.queued = 0.0
        report.again += message.again
        report.why += [message.why] if message.why else []
        report.role = message.role
        report.agents.append(message.agent)
        self.policy = make_partner(self.policies[report.role], report.role)
        self.policy.reset(policy_seed(self.seed + len(report.agents) - 1, report.role))
        await self.ws.send(Ready().encode())
        self.ready = time.monotonic()

    async def frame(self, message: StateView) -> bool:
        """A frame: the partner's keys for it, sent when they change; True once it leaves."""
        report = self.report
        if self.ready is not None:
            report.first_frames.append(time.monotonic() - self.ready)
            self.ready = None
        if self.policy is None or message.obs is None:
            return False
        report.states += 1
        if self.leave_after and report.states >= self.leave_after:
            return True
        keys = action_keys(self.policy.act(as_observation(message.obs, self.policy.view)))
        if keys != self.held:  # a person's keyboard reports changes, not frames
            self.held = keys
            await self.ws.send(keys.encode())
        return False


async def stand_in(
    url: str,
    policies: dict[str, str] | None = None,
    resume: tuple[str, str] | None = None,
    leave_after: int = 0,
    seed: int = 0,
    test: str = "",
    worker: str = "",
    sig: str = "",
    ssl: object = None,
    address: str | None = None,
    link: dict[str, str] | None = None,
    attentive: bool = True,
) -> StandInReport:
    """Take part in the study served at `url` (the page's address), playing each role with a partner
    by name (services/population/partners.py: a policy key, or `human(B5,input_ms=0)`, a stand-in
    person whose screen is the page itself; default: the scripted circle bait and mirror shooter),
    its trial k reset as in game seed `seed` + k - 1. `resume` = (participant, key) comes
    back as an earlier participant; `leave_after` > 0 drops the connection after that many frames,
    as a participant who walks away. `test` is the server's test token (Serving.test_token),
    without which it gets no observation values to play from; `worker` a crowd-sourcing worker
    id, `sig` its signed link's signature; `link` the link's other parameters (a platform's ids);
    `attentive` False answers every attention check with a wrong button; `ssl` an SSLContext for a
    wss:// server; `address` the local address it connects from (a loopback test's other clients:
    127.0.0.2 and on)."""
    hello = Hello(
        obs=True, test=test or None, worker=worker or None, sig=sig or None, link=link or None,
        **({"participant": resume[0], "key": resume[1]} if resume else {}),
    )  # fmt: skip
    socket = url.replace("http", "ws", 1).rstrip("/") + "/ws"
    local = {"local_addr": (address, 0)} if address else {}
    async with websockets.connect(socket, ssl=ssl, **local) as ws:
        visit = _Visit(ws, policies or {"bait": "circle", "shooter": "mirror"}, seed, leave_after, attentive)
        await ws.send(hello.encode())
        async for text in ws:
            if await visit.on(decode_down(text)):  # the page's contract, as the page reads it
                break
        return visit.report
