"""What a proxy learns from: a person's (observation, action) pairs out of recordings, and the split
of the people into those it learns from and those it is judged on.

A seat counts as a person's when the study's sidecar (`<match>.study.json`) names it as the
participant's `role`, else when the start record names no policy for it ("" or the launcher's
"human"); the other seat is an agent's and is left out, by name. An attempt the study marked other
than `done` (a participant who dropped out) is left out, by name. Everything else that is wrong
stops the whole run with one line, so that nothing is ever trained on part of what was asked:
an unreadable or damaged recording, a recording without a person's seat, a person who played the
other seat (roles mixed), too few people or frames.

Pairs: the world-view observation of frame f (what the sim published, docs/observation.md) and the
action the sim applied to step from f to f + 1 (frame f + 1's `applied`), for frames in which the
person's ship is alive (a dead ship's keys do nothing); beside each, the person's HISTORY actions
before it, latest first (0, no keys, before the game began), for a proxy that reads its own last
actions (keys held down). The participant is the sidecar's, else the
recording's own name (each recording then counts as a person of its own).
"""

from __future__ import annotations

import hashlib
import json
import random
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.recorder.recording import Recording, load
from services.sim import observation as ob
from shared.errors import Failure, UsageError
from shared.game import PERSON, ROLES, other

HELD_OUT = 0.25  # the share of participants held out
MIN_FRAMES = 300  # frames (10 s) that each side of the split needs at least
HISTORY = 4  # previous actions kept beside each pair


@dataclass(frozen=True)
class Source:
    """One recording used: where, its hash, whose play and how many pairs it gave."""

    path: str
    sha256: str
    participant: str
    frames: int


@dataclass
class Dataset:
    """The pairs of one seat, row by row, with whose they are."""

    role: str
    obs: np.ndarray  # (n, 64) float32, world view
    actions: np.ndarray  # (n,) int64, 0-11
    previous: np.ndarray  # (n, HISTORY) int64: the actions before, latest first
    people: np.ndarray  # (n,) int64 index into participants
    participants: list[str]
    sources: list[Source] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)  # "path: why", one per seat or attempt left out

    def rows(self, names: list[str]) -> np.ndarray:
        """Indices of the rows of these participants."""
        return np.flatnonzero(np.isin(self.people, [self.participants.index(n) for n in names]))


@dataclass(frozen=True)
class Split:
    train: list[str]
    held_out: list[str]


def study_record(path: Path) -> dict:
    """The study runner's sidecar beside a recording ({} when there is none)."""
    sidecar = path.with_name(path.name.removesuffix(".tsflog") + ".study.json")
    if not sidecar.exists():
        return {}
    try:
        record = json.loads(sidecar.read_text())
    except (OSError, ValueError) as error:
        raise Failure(f"{sidecar}: unreadable study sidecar ({error})") from None
    return record if isinstance(record, dict) else {}


def person_seats(recording: Recording, record: dict) -> list[str]:
    """The seats a person played: the sidecar's role, else the seats the start names no policy for."""
    if record.get("role") in ROLES:
        return [record["role"]]
    policies = recording.start.policies if recording.start else {}
    return [r for r in ROLES if policies.get(r, "") in PERSON]


def pairs(recording: Recording, role: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(observations, actions, previous actions) of `role`'s seat while its ship is alive (module
    docstring)."""
    states = {s.frame: s for s in recording.states}
    index = ROLES.index(role)
    obs, actions, previous = [], [], []
    for frame in sorted(states):
        after = states.get(frame + 1)
        values = states[frame].obs[role]
        if after is None or values[ob.SELF + ob.ALIVE] < 0.5:
            continue
        obs.append(values)
        actions.append(after.applied[index])
        before = (states.get(frame - k) for k in range(HISTORY))  # frame f's applied: the action at f - 1
        previous.append([s.applied[index] if s is not None and s.frame > 0 else 0 for s in before])
    return (
        np.asarray(obs, np.float32).reshape(-1, ob.TIME + 1),
        np.asarray(actions, np.int64),
        np.asarray(previous, np.int64).reshape(-1, HISTORY),
    )


def extract(paths: list[Path], role: str, by: str = "participant") -> Dataset:
    """The person's pairs of `role` from every recording (refusals and exclusions: module docstring).
    `by`: what the split draws, "participant" or, for one person's own proxy, "recording" (each
    recording is then a group of its own)."""
    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if not paths:
        raise UsageError("RECORDINGS", "(none)", "give at least one recording")
    chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, str]] = []
    empty = np.zeros(0, np.int64)
    data = Dataset(role, np.zeros((0, 64), np.float32), empty, np.zeros((0, HISTORY), np.int64), empty, [])
    for path in paths:
        path = Path(path)
        try:
            recording = load(path)
        except (OSError, ValueError) as error:
            raise Failure(f"{path}: unreadable recording ({error}); nothing trained") from None
        if problems := recording.problems():
            raise Failure(f"{path}: damaged recording ({'; '.join(problems)}); nothing trained")
        record = study_record(path)
        if record.get("status", "done") != "done":
            data.excluded.append(f"{path}: attempt marked {record['status']} by the study")
            continue
        seats = person_seats(recording, record)
        policies = recording.start.policies if recording.start else {}
        if not seats:
            named = ", ".join(f"{r} {policies.get(r)}" for r in ROLES)
            raise UsageError("RECORDINGS", path, f"has no person's seat (agents: {named}); nothing trained")
        if role not in seats:
            raise UsageError(
                "--role",
                role,
                f"{path}: the person played the {seats[0]} seat, not the {role} (one seat at a time); "
                "nothing trained",
            )
        if other(role) not in seats:
            data.excluded.append(f"{path}: {other(role)} seat, agent {policies.get(other(role)) or '?'}")
        obs, actions, previous = pairs(recording, role)
        participant = str(record.get("participant") or path.name.removesuffix(".tsflog"))
        participant = participant if by == "participant" else path.name.removesuffix(".tsflog")
        chunks.append((obs, actions, previous, participant))
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        data.sources.append(Source(str(path), digest, participant, len(actions)))
    data.participants = sorted({p for *_, p in chunks})
    if chunks:
        data.obs = np.concatenate([c[0] for c in chunks])
        data.actions = np.concatenate([c[1] for c in chunks])
        data.previous = np.concatenate([c[2] for c in chunks])
        data.people = np.concatenate([np.full(len(c[1]), data.participants.index(c[3])) for c in chunks])
    return data


def split(data: Dataset, held_out: float = HELD_OUT, seed: int = 0, min_frames: int = MIN_FRAMES) -> Split:
    """Participants drawn (by `seed`) into training and held-out sets, `held_out` of them (at least
    one) held out. Refused (Failure) with fewer than two people or `min_frames` on either side."""
    people = list(data.participants)
    if len(people) < 2:
        raise Failure(
            f"too little data: {len(people)} participant(s) ({', '.join(people) or 'none'}); "
            "a split by participant needs at least 2; nothing trained"
        )
    random.Random(seed).shuffle(people)
    n = min(len(people) - 1, max(1, round(held_out * len(people))))
    out = Split(sorted(people[n:]), sorted(people[:n]))
    for side, names in (("training", out.train), ("held-out", out.held_out)):
        frames = len(data.rows(names))
        if frames < min_frames:
            raise Failure(
                f"too little data: {frames} {side} frames ({', '.join(names)}), at least {min_frames} "
                "needed; nothing trained"
            )
    return out
