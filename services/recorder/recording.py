"""Reading a recording: decoded messages and a replay check (export.py: its tables as Parquet)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from services.recorder.log import Damage, read_log
from services.sim.engine import Game
from shared.game import GameConfig
from shared.messages import (
    Action,
    AdapterStatus,
    GameEvent,
    MessageError,
    PolicySwitch,
    Ruling,
    Start,
    State,
    Summary,
    decode_any,
)


@dataclass
class Recording:
    """The decoded content of one match's log, and every way it falls short of a complete one."""

    path: Path
    damage: list[Damage] = field(default_factory=list)  # stretches of the log the reader skipped
    start: Start | None = None
    summary: Summary | None = None
    states: list[State] = field(default_factory=list)
    actions: list[tuple[int, Action]] = field(default_factory=list)  # (receive time ns, action)
    switches: list[PolicySwitch] = field(default_factory=list)
    rulings: list[Ruling] = field(default_factory=list)  # the adapter's, one each scoring frame
    events: list[GameEvent] = field(default_factory=list)
    adapter: list[AdapterStatus] = field(default_factory=list)
    gaps: list[tuple[int, int]] = field(default_factory=list)
    undecodable: int = 0
    why: str = ""  # the first undecodable record's reason (MessageError), to say what is wrong
    duplicates: list[int] = field(default_factory=list)  # frames whose state came again (first kept)
    starts: int = 0  # start records: more than one means two matches in one log
    summaries: int = 0

    @property
    def clean(self) -> bool:
        return not self.damage

    @property
    def torn(self) -> bool:
        return bool(self.damage) and self.damage[-1].torn

    @property
    def missing_frames(self) -> int:
        return sum(last - first + 1 for first, last in self.gaps)

    def lost(self) -> list[tuple[int, int]]:
        """Ranges of frames up to the last one known (the summary's, else the last state's) whose
        state is in the log neither as a state nor inside a gap record: lost to damage."""
        last = self.summary.frame if self.summary else max((s.frame for s in self.states), default=-1)
        known = {s.frame for s in self.states} | {f for a, b in self.gaps for f in range(a, b + 1)}
        return _ranges(f for f in range(last + 1) if f not in known)

    @property
    def planned(self) -> int | None:
        """The frames the match was to last, as its start record's config says (None without one)."""
        frames = self.start.config.get("frames") if self.start is not None else None
        return frames if isinstance(frames, int) else None

    def problems(self, allow_torn: bool = False) -> list[str]:
        """What is missing or wrong, one phrase each; empty for a complete recording with a summary
        at the planned last frame (a stopped match's summary comes early: a fragment, never
        complete). `allow_torn`: a missing end (no summary, maybe a last record cut short) is no
        problem."""
        damaged = [d for d in self.damage if not d.torn or not allow_torn]
        last = max((s.frame for s in self.states), default=None)
        short = self.summary is not None and self.planned is not None and self.summary.frame < self.planned
        return [
            *([f"stopped at frame {self.summary.frame} of {self.planned}"] if short else []),
            *(str(d) for d in damaged),
            *([f"frames {_text(self.lost())} lost"] if self.lost() else []),
            *([f"frames {_text(self.gaps)} never reached the recorder"] if self.gaps else []),
            *(["no start record"] if self.start is None else []),
            *([f"no summary (last state: frame {last})"] if self.summary is None and not allow_torn else []),
            *([f"{self.starts} start records (more than one match)"] if self.starts > 1 else []),
            *([f"{self.summaries} summaries (more than one match)"] if self.summaries > 1 else []),
            *([f"frames {_text(_ranges(self.duplicates))} recorded twice"] if self.duplicates else []),
            *([f"{self.undecodable} undecodable records ({self.why})"] if self.undecodable else []),
        ]


def _ranges(frames: Iterable[int]) -> list[tuple[int, int]]:
    """Sorted frame numbers as ranges of consecutive ones."""
    out: list[tuple[int, int]] = []
    for frame in sorted(set(frames)):
        if out and out[-1][1] == frame - 1:
            out[-1] = (out[-1][0], frame)
        else:
            out.append((frame, frame))
    return out


def _text(ranges: list[tuple[int, int]]) -> str:
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in ranges)


def load(path: str | Path) -> Recording:
    records, damage = read_log(path)
    recording = Recording(Path(path), damage)
    seen: set[int] = set()
    for record in records:
        if record.gap is not None:
            recording.gaps.append(record.gap)
            continue
        try:
            message = decode_any(record.data)
        except MessageError as error:
            recording.undecodable += 1
            recording.why = recording.why or f"first: {error}"
            continue
        if isinstance(message, State):
            if message.frame in seen:
                recording.duplicates.append(message.frame)
                continue
            seen.add(message.frame)
            recording.states.append(message)
        elif isinstance(message, Action):
            recording.actions.append((record.t, message))
        elif isinstance(message, PolicySwitch):
            recording.switches.append(message)
        elif isinstance(message, Ruling):
            recording.rulings.append(message)
        elif isinstance(message, GameEvent):
            recording.events.append(message)
        elif isinstance(message, AdapterStatus):
            recording.adapter.append(message)
        elif isinstance(message, Start):
            recording.starts += 1
            recording.start = recording.start or message
        elif isinstance(message, Summary):
            recording.summaries += 1
            recording.summary = recording.summary or message
    return recording


def simulate(recording: Recording) -> Iterator[tuple[State, Game]]:
    """Re-simulate the match through the engine with the actions the sim applied: each recorded
    state beside the engine's game at that frame (the same Game object, stepped in place)."""
    if recording.start is None:
        raise ValueError(f"{recording.path}: no start record, so the match cannot be replayed")
    game = Game(GameConfig.from_dict(recording.start.config), recording.start.seed)
    by_frame = {s.frame: s for s in recording.states}
    for frame in range(0, max(by_frame, default=0) + 1):
        if frame > 0:
            if frame not in by_frame:
                raise ValueError(f"{recording.path}: frame {frame} is missing, so its actions are unknown")
            game.step(*by_frame[frame].applied)
        if frame in by_frame:
            yield by_frame[frame], game


def replay(recording: Recording) -> list[int]:
    """The frames whose recorded state hash differs from the re-simulated one (empty: every
    recorded state reproduced)."""
    return [state.frame for state, game in simulate(recording) if state.hash != game.state_hash()]
