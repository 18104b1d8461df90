"""The study's pure core: its config, who plays which role, in which order the agents come, what
is done and what comes next. No web server and no bus (services/study/runner.py is the shell).

The protocol is the original study's: a participant gets a role at random, balanced over
participants (permuted blocks of two), and plays one session of `trials` one-minute trials with
each agent variant, the variants in a random order of their own; the agents are shown only as
"Agent 1".."Agent N", numbered by session. A participant who drops out resumes at the trial that
was cut short, which is played again as a new attempt (the cut one stays recorded, marked dropped).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import json
import math
import os
import queue
import random
import re
import secrets
import threading
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from services.population.adaptive import AdapterConfig
from services.population.seat import AdaptiveSeat, SeatSpec
from services.study.crowd import FAILS, Crowd
from shared import config
from shared.errors import UsageError
from shared.game import DURATION, FPS, ROLES, SEEDS, other
from shared.secret import same_secret

NAME = re.compile(r"[A-Za-z0-9_]{1,24}")
DEFAULT_CONSENT = (
    "This study is about teamwork between people and computer agents in a video game. You will "
    "play {games} of {seconds} seconds each with different computer teammates, about "
    "{minutes} minutes in all. Your key presses and the games are recorded under a participant "
    "number, not your name. You may stop at any time."
)
SET_UP = 2.0  # seconds a game takes to set up on a warm pool (p99 under 1 s measured), as the page says
AROUND = 20.0  # seconds a game takes beyond its length (the offer read, Ready, its end): study and slot time
DEFAULT_END = "Thank you for taking part. You may close this window now."
REDIRECTED_END = "Thank you for taking part."  # the default end text where the page then redirects
# What the consent text says of a practice game and of attention checks where the study has them and
# the text does not place {practice} or {checks}: added at its end.
PRACTICE_TEXT = "Before them you play a practice game of {seconds} seconds, which does not count."
CHECKS_TEXT = (
    "Before some sessions a short attention check asks you to click the button it names; "
    "missing {fails} of them ends the study for you."
)
# Settings added after studies had begun: left out of the study's hash while at their default, so
# that a journal begun before they existed is still this study's (as a message's ADDED fields).
LATER = {"show_points": True}
PRACTICE = ("practice", "circle", "mirror")  # the practice partner: the library's scripted bait and shooter


@dataclass(frozen=True)
class Variant:
    """One agent the participants meet. `bait` is the agent's seat when the participant plays the
    shooter, `shooter` when the participant plays the bait; an adaptive variant names its adaptive
    agent (`adapter = "adaptive-T400-bayes-dwell-ood-guard"` in a config file,
    services/adapter/core.py AdapterConfig), which plays every seat the variant names no static
    policy for (the shipped adaptive study plays the static B1 in the bait seat: adapting the bait
    does not pay with people-like shooters, docs/adapter.md). Each is a SeatSpec, read from its
    name once (`read`)."""

    name: str
    bait: SeatSpec | None = None
    shooter: SeatSpec | None = None
    adapter: SeatSpec | None = None

    def __post_init__(self) -> None:
        name = self.name  # "S5" and "S5 " were two variants, the same on every page
        if not (0 < len(name) <= 64 and name.isprintable() and name == name.strip()):
            raise ValueError(f"variant name {self.name!r}: 1-64 printable characters, no blank at either end")
        if self.adapter and not isinstance(self.adapter, AdaptiveSeat):
            raise ValueError(f"variant {self.name}: {str(self.adapter)!r} names no adaptive agent")

    @classmethod
    def read(cls, name: str, bait: str = "", shooter: str = "", adapter: str = "") -> Variant:
        """The variant a study's config names (an empty name: none); a ValueError for a name that is
        no seat."""
        try:
            adaptive = SeatSpec.parse(adapter, "adapter") if adapter else None
        except ValueError:
            raise ValueError(f"variant {name}: {adapter!r} names no adaptive agent") from None
        return cls(
            name,
            *(SeatSpec.parse(n, role) if n else None for n, role in ((bait, "bait"), (shooter, "shooter"))),
            adaptive,
        )

    @property
    def names(self) -> dict[str, str]:
        """The variant as its config names it (the study's fingerprint hashes these)."""
        return {"name": self.name, **{f: str(getattr(self, f) or "") for f in ("bait", "shooter", "adapter")}}

    def adaptive(self, agent_role: str, seed: int) -> AdapterConfig | None:
        """The adaptive agent this variant plays in `agent_role`'s seat, or None for a static one."""
        seat = self.seat(agent_role)
        return seat.adaptive(agent_role, seed) if seat else None

    def seat(self, agent_role: str) -> SeatSpec:
        """What plays `agent_role`'s seat (MatchPlan's field of that name): the static policy the
        variant names for it, else its adaptive agent."""
        return getattr(self, agent_role) or self.adapter


@dataclass(frozen=True)
class StudyConfig:
    """A study's protocol: its variants and how many trials of how long; shown texts."""

    name: str
    variants: tuple[Variant, ...]
    trials: int = 3
    trial_seconds: float = 60.0
    seed: int = 0
    roles: tuple[str, ...] = ROLES  # the roles participants are given
    # What a participant agrees to: {games} ("15 games"), {seconds}, {minutes} (in all) and {pay}
    # are filled in from the config (`consent_text`); a `pay` the text does not place is added at its end.
    consent: str = DEFAULT_CONSENT
    pay: str = ""  # e.g. "GBP 2.50 through Prolific"
    end: str = DEFAULT_END
    instructions: dict[str, str] = field(default_factory=dict)  # role -> text; else the page's own
    # A practice game of this many seconds before the first recorded one (0: none), with a scripted
    # partner (PRACTICE); it is no trial: not in the journal, its recording apart in practice/.
    practice_seconds: float = 0.0
    crowd: Crowd = field(default_factory=Crowd)  # a platform's ids, redirects, bonus (study/crowd.py)
    # The page shows the team's points beside the fortresses destroyed, and how they are counted;
    # false: only the fortresses destroyed (the study's score), points neither shown nor explained.
    show_points: bool = True

    def __post_init__(self) -> None:
        if not NAME.fullmatch(self.name):
            raise ValueError(f"study name {self.name!r}: use 1-24 letters, digits or '_'")
        if not self.variants:
            raise ValueError("a study needs at least one variant")
        if len({v.name for v in self.variants}) != len(self.variants):
            raise ValueError("variant names must differ")
        if self.trials < 1:
            raise ValueError("need at least one trial")
        if self.trial_seconds not in DURATION:
            raise ValueError(f"trial_seconds {self.trial_seconds}: outside the range {DURATION}")
        if self.practice_seconds and self.practice_seconds not in DURATION:
            raise ValueError(f"practice_seconds {self.practice_seconds}: 0 (none) or in the range {DURATION}")
        if self.seed not in SEEDS:
            raise ValueError(f"seed {self.seed}: outside the range {SEEDS}")
        if not self.roles or not set(self.roles) <= set(ROLES):
            raise ValueError(f"roles must be among {ROLES}")
        if not set(self.instructions) <= set(ROLES):
            raise ValueError(f"instructions: a text per role, among {ROLES}; not {sorted(self.instructions)}")
        try:
            self.consent_text()
        except (KeyError, IndexError, ValueError) as error:
            raise ValueError(
                f"consent: cannot fill in {error} (the text may name {{games}}, {{seconds}}, "
                "{minutes}, {pay}, {practice} and {checks}; a brace itself is written {{ or }})"
            ) from None
        if any(s > len(self.variants) for s in self.crowd.attention_checks):
            raise ValueError(f"crowd.attention_checks: sessions are 1 to {len(self.variants)}")
        for variant in self.variants:
            for role in self.roles:
                agent = other(role)
                if not variant.adapter and not getattr(variant, agent):
                    raise ValueError(f"variant {variant.name} has no {agent} for a {role} participant")

    @property
    def frames(self) -> int:
        return round(self.trial_seconds * FPS)

    def consent_text(self) -> str:
        """The consent text as shown: the study's numbers filled in, what comes besides the games (a
        practice game, attention checks) and its pay; each the text does not place is added."""
        games = self.trials * len(self.variants)
        minutes = math.ceil((games * (self.trial_seconds + AROUND) + self.practice_seconds) / 60)
        counted = f"{games} game{'s' if games != 1 else ''}"
        practice = PRACTICE_TEXT.format(seconds=f"{self.practice_seconds:g}") if self.practice_seconds else ""
        checks = CHECKS_TEXT.format(fails=FAILS) if self.crowd.attention_checks else ""
        shown = self.consent.format(
            games=counted, seconds=f"{self.trial_seconds:g}", minutes=minutes, pay=self.pay,
            practice=practice, checks=checks,
        )  # fmt: skip
        placed = {name: f"{{{name}}}" in self.consent for name in ("practice", "checks")}
        added = [text for name, text in (("practice", practice), ("checks", checks)) if not placed[name]]
        shown = " ".join([shown, *filter(None, added)])
        return shown if not self.pay or "{pay}" in self.consent else f"{shown}\n\nPay: {self.pay}"

    def end_text(self, redirected: bool) -> str:
        """The end text as shown: the default one tells the participant to close the window only
        where no redirect takes them back to the platform."""
        return REDIRECTED_END if redirected and self.end == DEFAULT_END else self.end

    @classmethod
    def load(cls, path: str | Path) -> StudyConfig:
        """Read a study's TOML file (services/study/configs/ has the original two experiments); a
        file that is not a study's is a UsageError that says why."""
        try:
            return config.build(cls, tomllib.loads(Path(path).read_text()))
        except UnicodeDecodeError:
            raise UsageError("CONFIG", path, "not a study: not text (UTF-8)") from None
        except ValueError as error:  # TOML syntax, unknown or missing settings, bad kinds or values
            raise UsageError("CONFIG", path, f"not a study: {error}") from None

    def hash(self) -> str:
        """The protocol's fingerprint; the platform's logistics (`crowd`) may change mid-study."""
        protocol = {
            k: v
            for k, v in dataclasses.asdict(self).items()
            if k != "crowd" and not (k in LATER and LATER[k] == v)
        }
        protocol["variants"] = [variant.names for variant in self.variants]
        if self.crowd.attention_checks:  # these do change what participants go through
            protocol["attention_checks"] = self.crowd.attention_checks
        text = json.dumps(protocol, sort_keys=True)
        return hashlib.blake2b(text.encode(), digest_size=8).hexdigest()


def assigned_role(config: StudyConfig, index: int) -> str:
    """Participant `index`'s role: permuted blocks over the study's roles, so that the counts never
    differ by more than one block, and each block's order is random (seeded by the study)."""
    roles = list(config.roles)
    block, place = divmod(index, len(roles))
    random.Random(f"{config.seed}/roles/{block}").shuffle(roles)
    return roles[place]


def variant_order(config: StudyConfig, index: int) -> list[int]:
    """The order in which participant `index` meets the variants (indices into config.variants)."""
    order = list(range(len(config.variants)))
    random.Random(f"{config.seed}/order/{index}").shuffle(order)
    return order


@dataclass(frozen=True)
class Trial:
    """One attempt at one trial: where it sits in the protocol, and the match that plays it."""

    participant: str
    role: str
    session: int  # 1-based: session k is played with "Agent k"
    trial: int  # 1-based within the session
    attempt: int  # 1, or more after drop-outs
    variant: Variant
    match: str
    seed: int
    practice: bool = False  # the practice game: no trial of the protocol

    @property
    def agent(self) -> str:
        return "a practice partner" if self.practice else f"Agent {self.session}"


@dataclass
class Participant:
    """One participant's assignment and progress, as stored in the study's file."""

    id: str
    key: str  # the secret that lets the participant's browser resume
    index: int
    role: str
    order: list[int]
    attempts: list[dict] = field(default_factory=list)  # {session, trial, attempt, match, status, kills}
    worker: str = ""  # the crowd-sourcing platform's worker id, if the link gave one
    code: str = ""  # the completion code shown at the end (for the platform's payment)
    link: dict[str, str] = field(default_factory=dict)  # the platform's study and session ids, if given
    checks: list[bool] = field(default_factory=list)  # each attention check answered: passed?
    refused: list[str] = field(default_factory=list)  # each time they came back and were refused: why

    @property
    def screened(self) -> bool:
        """Screened out: failed FAILS attention checks (services/study/crowd.py)."""
        return self.checks.count(False) >= FAILS

    def done(self, session: int, trial: int) -> bool:
        return any(
            a["session"] == session and a["trial"] == trial and a["status"] == "done" for a in self.attempts
        )


class Journal:
    """An append-only file of JSON lines, written by a thread of its own: the caller (the web
    server's event loop) never waits for the disk, and each line is flushed and synced before the
    next, so a crash loses at most the lines not yet written and never garbles earlier ones (a torn
    last line is skipped when read)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.lines: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._write, daemon=True)
        self.thread.start()

    @staticmethod
    def read(path: Path) -> list[dict]:
        records = []
        for line in path.read_text().splitlines() if path.exists() else []:
            try:
                records.append(json.loads(line))
            except ValueError:  # a line cut short by a crash: only ever the last
                break
        return records

    def append(self, record: dict) -> None:
        self.lines.put(json.dumps(record, separators=(",", ":")))

    def close(self) -> None:
        """Write what is queued, then stop."""
        self.lines.put(None)
        self.thread.join()

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a") as out:
            while (line := self.lines.get()) is not None:
                out.write(line + "\n")
                out.flush()
                os.fsync(out.fileno())


WORKER = re.compile(r"[A-Za-z0-9_.:@+-]{1,64}")  # what a platform's worker id may hold


def worker_id(given: object) -> str | None:
    """A crowd-sourcing worker id as the link gave it, without surrounding spaces; "" for none;
    None for anything that is no id (not a string, control characters, markup, over 64)."""
    if given is None or given == "":
        return ""
    if not isinstance(given, str):
        return None
    trimmed = given.strip()
    return trimmed if WORKER.fullmatch(trimmed) else None


def _seed(match: str) -> int:
    """A game's seed from its match id: fixed by the protocol, different for every attempt."""
    return int.from_bytes(hashlib.blake2b(match.encode(), digest_size=4).digest(), "big")


class Study:
    """Participants and their progress, kept in the journal `<directory>/study.jsonl`: a header,
    then one line per new participant and one per change of an attempt. Read back on start, so a
    restarted server resumes everyone; a trial that was running when it stopped is played again."""

    def __init__(self, config: StudyConfig, directory: str | Path) -> None:
        self.config, self.directory = config, Path(directory)
        self.path = self.directory / "study.jsonl"
        self.participants: dict[str, Participant] = {}
        self.workers: dict[str, str] = {}  # worker id, casefolded -> participant id
        records = Journal.read(self.path)
        if records and records[0].get("config") != config.hash():
            raise ValueError(f"{self.path} belongs to another version of study {records[0].get('study')!r}")
        for record in records[1:]:
            if "participant" in record:
                self._add(Participant(**record["participant"]))
            elif "check" in record:
                self.participants[record["id"]].checks.append(record["check"])
            elif "refused" in record:
                self.participants[record["id"]].refused.append(record["refused"])
            else:
                self._attempt(record["id"], record["attempt"])
        self.journal = Journal(self.path)
        if not records:
            self.journal.append({"study": config.name, "config": config.hash()})

    def close(self) -> None:
        self.journal.close()

    def _add(self, participant: Participant) -> None:
        self.participants[participant.id] = participant
        if participant.worker:
            self.workers[participant.worker.casefold()] = participant.id

    def taken(self, worker: str) -> bool:
        """Whether this crowd-sourcing worker id (in any case) has already taken part."""
        return bool(worker) and worker.casefold() in self.workers

    def _attempt(self, participant: str, entry: dict) -> None:
        found = self.participants[participant]
        same = ("session", "trial", "attempt")
        found.attempts = [a for a in found.attempts if any(a[k] != entry[k] for k in same)] + [entry]

    def arrive(self, worker: str = "", link: dict[str, str] | None = None) -> Participant:
        """A new participant, who has consented: the next id, a role, an order of variants and a
        completion code. A worker id already seen is the shell's to refuse (`taken`)."""
        index = len(self.participants)
        participant = Participant(
            f"P{index + 1:03d}",
            secrets.token_urlsafe(9),
            index,
            assigned_role(self.config, index),
            variant_order(self.config, index),
            worker=worker,
            code=secrets.token_hex(4).upper(),
            link=link or {},
        )
        self._add(participant)
        self.journal.append({"participant": dataclasses.asdict(participant)})
        return participant

    def check(self, participant: Participant, passed: bool) -> None:
        """Write down an attention check's outcome."""
        participant.checks.append(passed)
        self.journal.append({"id": participant.id, "check": passed})

    def by_worker(self, worker: str) -> Participant:
        """The participant of a crowd-sourcing worker id that has taken part (`taken`)."""
        return self.participants[self.workers[worker.casefold()]]

    def refused(self, participant: Participant, why: str) -> None:
        """Write down that a returning participant was refused, and why (a short code)."""
        participant.refused.append(why)
        self.journal.append({"id": participant.id, "refused": why})

    def resume(self, participant: str, key: str) -> Participant | None:
        """The participant with this id and key, or None."""
        found = self.participants.get(participant)
        return found if found is not None and same_secret(key, found.key) else None

    def next_trial(self, participant: Participant) -> Trial | None:
        """The first trial the participant has not completed, or None when all are done."""
        for session in range(1, len(participant.order) + 1):
            for trial in range(1, self.config.trials + 1):
                if participant.done(session, trial):
                    continue
                attempt = 1 + sum(
                    a["session"] == session and a["trial"] == trial for a in participant.attempts
                )
                return self._trial(participant, session, trial, attempt)
        return None

    def _trial(self, participant: Participant, session: int, trial: int, attempt: int) -> Trial:
        match = f"{self.config.name}-{participant.id}-s{session}t{trial}" + (
            f"-a{attempt}" if attempt > 1 else ""
        )
        variant = self.config.variants[participant.order[session - 1]]
        return Trial(participant.id, participant.role, session, trial, attempt, variant, match, _seed(match))

    def practice(self, participant: Participant) -> Trial | None:
        """The practice game before the participant's first recorded one, or None (none configured,
        or the recorded ones begun). A new match id each time: a reload plays it again."""
        if not self.config.practice_seconds or participant.attempts:
            return None
        match = f"{self.config.name}-{participant.id}-practice-{secrets.token_hex(3)}"
        return Trial(
            participant.id, participant.role, 1, 1, 1, Variant.read(*PRACTICE), match, _seed(match), True
        )

    def unsettled(self) -> list[Trial]:
        """The attempts left `running` or `dropped` (a server killed mid-trial, a page closed): each
        is for its recording to settle, `done` or `failed`."""
        return [
            self._trial(participant, a["session"], a["trial"], a["attempt"])
            for participant in self.participants.values()
            for a in participant.attempts
            if a["status"] in ("running", "dropped")
        ]

    def record(self, trial: Trial, status: str, kills: int | None = None) -> dict:
        """Write down how an attempt went (`running`, `dropped` while it runs out, then `done` or
        `failed`); returns the sidecar that goes beside the trial's recording."""
        participant = self.participants[trial.participant]
        entry = {"session": trial.session, "trial": trial.trial, "attempt": trial.attempt}
        self._attempt(participant.id, {**entry, "match": trial.match, "status": status, "kills": kills})
        self.journal.append({"id": participant.id, "attempt": participant.attempts[-1]})
        return {
            "study": self.config.name,
            "config": self.config.hash(),
            "participant": participant.id,
            "role": participant.role,
            "variant": trial.variant.name,
            "agent": trial.agent,
            **entry,
            "match": trial.match,
            "seed": trial.seed,
            "status": status,
            "kills": kills,
        }


class Admission:
    """Where and when trials' matches run: at most `cap` at once on this machine (LOCAL), plus as
    many as each live match host has slots (`hosts`, name -> slots, kept up to date by the shell);
    the trials that must wait are served in arrival order. While `held` (this machine's running
    matches fall behind, Lag), no new match starts here until it catches up, unless none runs here.

    A trial asks with `start(match)`: True if it may start now (it then holds a slot, `running[match]`
    says where, until `end`), else it joins the queue, and `place(match)` says how many wait before
    it, itself included. Local slots are filled first; remote hosts add capacity, the one with the
    most free slots first. A host that goes away keeps its running matches counted until they end."""

    LOCAL = ""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.hosts: dict[str, int] = {}
        self.running: dict[str, str] = {}  # match -> where it runs: LOCAL or a host's name
        self.waiting: list[str] = []
        self.held = False  # no new match here while this machine falls behind (Lag); hosts still take them

    def free(self) -> dict[str, int]:
        """Free slots by place, local first, then hosts by most free (ties by name)."""
        used: dict[str, int] = {}
        for where in self.running.values():
            used[where] = used.get(where, 0) + 1
        local = min(self.cap, used.get(self.LOCAL, 0)) if self.held and used.get(self.LOCAL) else self.cap
        slots = {self.LOCAL: local, **self.hosts}
        free = {where: n - used.get(where, 0) for where, n in slots.items() if n > used.get(where, 0)}
        hosts = sorted((w for w in free if w != self.LOCAL), key=lambda w: (-free[w], w))
        return {w: free[w] for w in ([self.LOCAL] if self.LOCAL in free else []) + hosts}

    def start(self, match: str) -> bool:
        if match not in self.waiting:
            self.waiting.append(match)
        free = self.free()
        if self.waiting.index(match) < sum(free.values()):
            self.waiting.remove(match)
            self.running[match] = next(iter(free))
            return True
        return False

    def place(self, match: str) -> int:
        return self.waiting.index(match) + 1 - sum(self.free().values())

    def end(self, match: str) -> None:
        """The match has ended, or the trial gave up waiting."""
        self.running.pop(match, None)
        if match in self.waiting:
            self.waiting.remove(match)

    def wait(self, place: int, match_seconds: float) -> float:
        """About how long the trial at `place` waits: every `slots` matches that end free a slot
        for the next `slots` in the queue (a running match is half over, on average)."""
        slots = max(1, self.cap + sum(self.hosts.values()))
        return (math.ceil(place / slots) - 0.5) * match_seconds


class Lag:
    """How late the running matches' frames reach the study server, the worst over the last
    `window` seconds: each state's arrival against the earliest its frame number allows (its
    match's best so far). The sims, agents and recorder of the running matches share the machine
    with every new one; a machine that falls behind shows it here first, so the server admits no
    new match while the worst is over its limit (Admission.held). Fed from zenoh's threads."""

    def __init__(self, window: float = 5.0) -> None:
        self.window = window
        self.origins: dict[str, float] = {}  # match -> its earliest arrival less frame / FPS
        self.recent: collections.deque[tuple[float, float]] = collections.deque()  # (arrival, lateness)
        self.lock = threading.Lock()

    def frame(self, match: str, frame: int, now: float) -> None:
        origin = now - frame / FPS
        with self.lock:
            best = min(origin, self.origins.get(match, origin))
            self.origins[match] = best
            self.recent.append((now, origin - best))
            while self.recent and self.recent[0][0] < now - self.window:
                self.recent.popleft()

    def worst(self, now: float) -> float:
        """Seconds: the latest frame of the last `window` seconds, against its match's best."""
        with self.lock:
            while self.recent and self.recent[0][0] < now - self.window:
                self.recent.popleft()
            return max((late for _, late in self.recent), default=0.0)

    def end(self, match: str) -> None:
        with self.lock:
            self.origins.pop(match, None)
