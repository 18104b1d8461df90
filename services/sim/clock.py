"""One clock for every match of a sim process: a single loop that plays each match's tick when it
is due, so many matches cost one thread, and none can stall another by a loop of its own."""

from __future__ import annotations

import threading
import time
from typing import Protocol

POLL = 0.05  # seconds between looks at the stop event while nothing is due


class Played(Protocol):
    """A match as the clock plays it (service.MatchSim). `due` is read under the clock's lock."""

    match: str
    closed: bool

    def due(self, now: float) -> float:
        """When the match's next tick is due (monotonic seconds; `now` or earlier: at once)."""

    def tick(self) -> None:
        """Play what is due: start, one frame, the summary, or the close."""

    def end(self) -> None:
        """End the match at its next tick (its summary is published)."""


class Clock:
    """Plays every match it holds: sleeps until the earliest due tick (woken early by `changed`,
    which the bus's callbacks notify when a match may be due sooner: a seat arrives, a lockstep
    answer, an order) and plays each due match's tick, earliest first. A match's ticks are due on
    its own schedule, so lateness never accumulates; a closed match is dropped."""

    def __init__(self) -> None:
        self.changed = threading.Condition()
        self.matches: list[Played] = []

    def add(self, match: Played) -> None:
        with self.changed:
            self.matches.append(match)
            self.changed.notify_all()

    def end(self, match: str) -> None:
        """End the match of that id at its next tick, if the clock plays it."""
        with self.changed:
            for played in self.matches:
                if played.match == match:
                    played.end()
            self.changed.notify_all()

    def run(self, stop: threading.Event, until_empty: bool = False) -> None:
        """Play until `stop` is set (then end every match and return once all are closed), or with
        `until_empty` until no match is left."""
        changed = self.changed
        while True:
            with changed:
                if stop.is_set():
                    for match in self.matches:
                        match.end()
                self.matches = [m for m in self.matches if not m.closed]
                if not self.matches and (until_empty or stop.is_set()):
                    return
                now = time.monotonic()
                dues = sorted((m.due(now), n, m) for n, m in enumerate(self.matches))
                if not dues or dues[0][0] > now:
                    changed.wait(min(dues[0][0] - now, POLL) if dues else POLL)
                    continue
            self._play([match for due, _, match in dues if due <= now])

    @staticmethod
    def _play(due: list[Played]) -> None:
        """Tick each match in `due`: a function of its own, so that no local of the loop holds an
        ended match."""
        for match in due:
            match.tick()
