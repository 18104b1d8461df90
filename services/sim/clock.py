"""One clock for every match of a sim process: a single loop that plays each match's tick when it
is due, so many matches cost one thread, and none can stall another by a loop of its own.

Matches tick in a few phases of the period (`phases`): each match is put in the least used, and its
ticks fall on that phase of the monotonic clock's grid. The matches of a phase are played in one pass
of the loop, so their states leave together: one wake-up of the clock and of each receiver's
network thread serves several matches. A pool's 12 matches cost about a fifth less CPU in 4 phases
than each on its own (bench/study.py: 0.060 -> 0.048-0.053 CPU-s per second of play per
participant), at a like tick jitter on a quiet machine (it varies from run to run) and a much lower
one on a loaded machine; all in one phase is a little cheaper still, but the last match of a pass
then waits for eleven others and jitter reached 5 ms (docs/architecture.md, "Pools"). The pool
plays in 8 phases: at 24 matches, a pass of 6 took 3.4 ms (p99 5.7) and one of 3 took 1.4 ms (p99
3.5), and the later matches of a long pass carry its variation as tick jitter."""

from __future__ import annotations

import threading
import time
from collections import Counter
from typing import Protocol

POLL = 0.05  # seconds between looks at the stop event while nothing is due


class Played(Protocol):
    """A match as the clock plays it (service.MatchSim). `due` is read under the clock's lock."""

    match: str
    closed: bool
    phase: float  # where in the period its ticks fall (0 <= phase < 1); set by the clock that plays it

    def due(self, now: float) -> float:
        """When the match's next tick is due (monotonic seconds; `now` or earlier: at once)."""

    def tick(self) -> None:
        """Play what is due: start, one frame, the summary, or the close."""

    def end(self) -> None:
        """End the match at its next tick (its summary is published)."""


def on_phase(now: float, period: float, phase: float) -> float:
    """The latest time at or before `now` on `phase` of the period's grid (monotonic seconds): a
    match whose ticks count from it ticks on its phase, its next tick at most a period away."""
    return now - (now - phase * period) % period


class Clock:
    """Plays every match it holds: sleeps until the earliest due tick (woken early by `changed`,
    which the bus's callbacks notify when a match may be due sooner: a seat arrives, a lockstep
    answer, an order) and plays each due match's tick, earliest first. A match's ticks are due on
    its own schedule, so lateness never accumulates; a closed match is dropped."""

    def __init__(self, phases: int = 1) -> None:
        self.changed = threading.Condition()
        self.matches: list[Played] = []
        self.phases = phases

    def add(self, match: Played) -> None:
        """Play `match` from now on, in the phase that the fewest of the matches held use."""
        with self.changed:
            used = Counter(round(m.phase * self.phases) for m in self.matches if not m.closed)
            match.phase = min(range(self.phases), key=lambda phase: (used[phase], phase)) / self.phases
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
