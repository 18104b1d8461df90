import threading
import time
from dataclasses import dataclass, field

import pytest

from services.sim.clock import Clock, on_phase


@dataclass
class Ticking:
    """A match of `ticks` ticks, one a period on its phase, that notes when each was played."""

    match: str
    ticks: int
    period: float = 0.05
    phase: float = 0.0
    closed: bool = False
    started: float | None = None
    played: list[float] = field(default_factory=list)

    def due(self, now: float) -> float:
        if self.started is None:
            self.started = on_phase(now, self.period, self.phase)
        return self.started + (len(self.played) + 1) * self.period

    def tick(self) -> None:
        self.played.append(time.monotonic())
        self.closed = len(self.played) >= self.ticks

    def end(self) -> None:
        self.closed = True


def test_on_phase_is_the_latest_grid_time_of_the_phase():
    assert on_phase(10.25, 1.0, 0.0) == pytest.approx(10.0)
    assert on_phase(10.25, 1.0, 0.5) == pytest.approx(9.5)
    assert on_phase(10.5, 1.0, 0.5) == pytest.approx(10.5)  # on the phase: now itself
    assert on_phase(10.25, 0.5, 0.75) == pytest.approx(9.875)


def test_each_match_goes_to_the_least_used_phase():
    clock = Clock(4)
    matches = [Ticking(f"m{n}", 1) for n in range(6)]
    for match in matches[:5]:
        clock.add(match)
    assert [m.phase for m in matches[:5]] == [0.0, 0.25, 0.5, 0.75, 0.0]
    matches[1].closed = True  # an ended match frees its phase
    clock.add(matches[5])
    assert matches[5].phase == 0.25


def test_matches_tick_on_their_phases():
    clock = Clock(2)
    matches = [Ticking(f"m{n}", 10) for n in range(2)]
    for match in matches:
        clock.add(match)
    thread = threading.Thread(target=clock.run, args=(threading.Event(), True))
    thread.start()
    thread.join(5)
    assert not thread.is_alive()
    for match in matches:
        assert len(match.played) == 10
        # played on its phase of the grid: never early, and (on a loaded machine) at most a few ms late
        lateness = [(t - match.phase * match.period) % match.period for t in match.played]
        assert all(late < match.period / 2 for late in lateness), lateness
