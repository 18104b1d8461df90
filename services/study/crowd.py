"""Crowd-sourcing as labs run it, Prolific's conventions by default: the platform's participant,
study and session ids from the link's parameters, a completion redirect and a separate
screened-out redirect, fair attention checks, and a bonus over the kills or points of the
recorded trials, written as the platform's bulk-bonus file (one `participant id,amount` line each).

Attention checks follow Prolific's policy (Researcher Help Centre, "Prolific's attention and
comprehension check policy"): each is explicitly instructed in the question itself ("click the
button that says BLUE"), its word changes from check to check (never repeated, unchanging text),
it needs no memory, and a participant is screened out only after failing two (the policy's
minimum for a study of five minutes or more). The study server
(runner.py) calls it; all but `write_bonuses` (which reads the recordings) is pure."""

from __future__ import annotations

import csv
import io
import random
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, urlsplit

from services.recorder.recording import load
from services.recorder.service import recording_path
from shared.page import Check

BONUSES = "bonuses.csv"  # in the study's directory
RESUMES = ("session", "never")  # Crowd.resume's values
FAILS = 2  # failed attention checks that screen a participant out (Prolific's minimum)
WORDS = ("RED", "GREEN", "BLUE", "PURPLE", "ORANGE", "YELLOW")


@dataclass(frozen=True)
class Bonus:
    """Pay per fortress destroyed (`per_kill`) and per point (`per_point`, points below zero count
    as zero) over a participant's completed trials, at most `max`, in `currency` (the platform
    pays in the study's own currency; the file holds amounts only)."""

    per_kill: float = 0.0
    per_point: float = 0.0
    max: float = 0.0
    currency: str = "GBP"

    def __post_init__(self) -> None:
        if min(self.per_kill, self.per_point, self.max) < 0 or not self.max:
            raise ValueError("bonus: per_kill and per_point must be 0 or more, and max above 0")

    def amount(self, trials: list[tuple[int, int]]) -> float:
        """The bonus for completed trials given as (kills, points), rounded to the cent."""
        earned = sum(self.per_kill * kills + self.per_point * max(points, 0) for kills, points in trials)
        return round(min(earned, self.max), 2)


@dataclass(frozen=True)
class Crowd:
    """How the study meets a crowd-sourcing platform. `participant`, `study`, `session`: the link's
    parameter names of its ids; `completion_url` and `screened_out_url`: where the page sends a
    participant who finished or was screened out (`{code}` is replaced by the completion code;
    empty: no redirect); `bonus`: the pay rule, if any; `attention_checks`: the sessions before
    whose first trial an attention check comes."""

    participant: str = "PROLIFIC_PID"
    study: str = "STUDY_ID"
    session: str = "SESSION_ID"
    completion_url: str = ""
    screened_out_url: str = ""
    # The platform's own completion code (Prolific's `cc`, fixed per study): shown at the end and put
    # in for `{code}`; empty: each participant's own code (the journal keeps it either way).
    completion_code: str = ""
    # Whom a participant contacts when the study cannot go on for them (a refusal, a stop): shown
    # on the page, e.g. "the researcher through Prolific's messages" or an address.
    contact: str = ""
    # Who may come back through the platform's link (a worker id that has begun): "session", one
    # whose link carries the platform's session id they began with; "never", none (only the study's
    # own resume link, participant id and key). With a link secret, any link signed for the id.
    resume: str = "session"
    bonus: Bonus | None = None
    attention_checks: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if any(not isinstance(s, int) or s < 1 for s in self.attention_checks):
            checks = list(self.attention_checks)
            raise ValueError(f"crowd.attention_checks {checks}: give session numbers, 1 and on")
        for name, most in (("completion_code", 64), ("contact", 200)):
            if len(getattr(self, name)) > most or not getattr(self, name).isprintable():
                raise ValueError(f"crowd.{name}: at most {most} printable characters")
        if self.completion_code != self.completion_code.strip():  # "   " was shown as the code
            raise ValueError(
                f"crowd.completion_code {self.completion_code!r}: the platform's code, without blanks at "
                "either end (or leave it out: each participant's own code)"
            )
        if self.resume not in RESUMES:
            raise ValueError(f"crowd.resume {self.resume!r}: one of {', '.join(RESUMES)}")
        for name in ("completion_url", "screened_out_url"):
            url = getattr(self, name)
            if url and (urlsplit(url).scheme not in ("https", "http") or not urlsplit(url).netloc):
                raise ValueError(f"crowd.{name} {url!r}: give an http(s) address")

    def code(self, own: str) -> str:
        """The completion code a participant is shown and sent back with: the platform's, if the
        study gives it, else their `own`."""
        return self.completion_code or own

    def redirect(self, url: str, code: str) -> str:
        """The address to send the participant to, with their completion code filled in."""
        return url.replace("{code}", quote(code, safe=""))

    def check_due(self, session: int, trial: int, answered: int) -> bool:
        """Whether an attention check comes before this trial, `answered` checks in (a participant
        who resumes past a check's session is asked it before going on)."""
        return trial == 1 and sum(s <= session for s in self.attention_checks) > answered

    def ids(self, link: dict[str, str]) -> tuple[str, str, str]:
        """The platform's (participant, study, session) ids as the link gave them ("" if not)."""
        return link.get(self.participant, ""), link.get(self.study, ""), link.get(self.session, "")


def attention_check(seed: str) -> tuple[Check, str]:
    """An attention check (the page's `check` message: its text and buttons) and the answer that
    passes it; the word and the buttons' order are drawn from `seed`."""
    rng = random.Random(seed)
    options = rng.sample(WORDS, 4)
    word = rng.choice(options)
    text = f'Attention check: to show that you are reading, please click the button that says "{word}".'
    return Check(text=text, options=options), word


def bonus_file(rows: list[tuple[str, float]]) -> str:
    """The bulk-bonus file a platform takes: one `participant id,amount` line each, no header (as
    Prolific's "Bulk bonus payments" box asks), amounts with two decimals, none of zero."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerows((who, f"{amount:.2f}") for who, amount in rows if amount > 0)
    return out.getvalue()


def write_bonuses(rule: Bonus | None, participants: Iterable, directory: Path) -> Path | None:
    """Each participant's bonus under `rule`, from the summaries of their completed trials'
    recordings, written to `<directory>/bonuses.csv` under the platform's participant id (the
    study's own where the link gave none); None if the study pays no bonus. `participants` are the
    study's (core.Participant: this module sits below the core, which reads its config)."""
    if rule is None:
        return None
    rows = []
    for participant in participants:
        trials = []
        for attempt in participant.attempts:
            if attempt["status"] == "done":
                summary = load(recording_path(directory / "recordings", attempt["match"])).summary
                trials.append((summary.kills, summary.points) if summary else (0, 0))
        rows.append((participant.worker or participant.id, rule.amount(trials)))
    path = directory / BONUSES
    path.write_text(bonus_file(rows))
    return path
