"""Whole matches with every service in its own process: results, recordings, and crashes mid-match."""

from __future__ import annotations

import itertools
import signal
import time
from collections import Counter

import pytest

from services.agent.scripted import CircleBait, MirrorShooter
from services.recorder.recording import load, replay
from services.recorder.service import recording_path
from services.runtime.launch import MatchPlan, run_match
from services.sim.play import play
from shared.game import ROLES, GameConfig
from shared.messages import State, Summary

SEED = 6  # a seed whose 150-frame game has points and deaths to compare (no kill is that quick)
REALTIME_FRAMES = 180  # 6 s
POLICIES = {"bait": "circle", "shooter": "mirror"}


def test_a_lockstep_match_equals_the_in_process_game(tmp_path):
    plan = MatchPlan("e2e", seed=SEED, frames=150, mode="lockstep", directory=tmp_path)
    summary, path = run_match(plan)
    expected = play(CircleBait(), MirrorShooter(), SEED, GameConfig(frames=150))
    assert (summary.frame, summary.kills, summary.points, summary.counters) == (
        expected.frames, expected.kills, expected.points, expected.counters,
    )  # fmt: skip
    assert summary.drops == {}
    recording = load(path)
    assert recording.clean and recording.gaps == [] and len(recording.states) == 151
    assert replay(recording) == []
    answers = Counter((a.role, a.frame) for _, a in recording.actions)  # the last state's may be cut off
    assert set(answers) >= set(itertools.product(ROLES, range(150))) and max(answers.values()) == 1


class LiveMatch:
    """A real-time match whose processes the test starts (and kills) itself, as run_match would."""

    def __init__(self, bus, spawn, tap, directory, match: str) -> None:  # noqa: ANN001 - fixtures
        bus.low_latency = MatchPlan.low_latency  # every peer must agree, and run_match's use it
        self.spawn, self.match, self.directory = spawn, match, directory
        common = ("--match", match, "--seed", str(SEED))
        sim = ("--frames", str(REALTIME_FRAMES), "--sim-mode", "realtime", "--wait-recorder", "10")
        self.commands = {
            "sim": ("sim", bus.config(listen=True), *common, *sim, "--bait", "circle", "--shooter", "mirror"),
            "recorder": ("recorder", bus.config(), "--match", match, "--out", str(directory)),
            **{r: ("agent", bus.config(), *common, "--role", r, "--policy", p) for r, p in POLICIES.items()},
        }
        self.processes = {name: spawn(*command) for name, command in self.commands.items()}
        self.tap = tap(bus.open(), match)

    def start(self, name: str) -> None:
        self.processes[name] = self.spawn(*self.commands[name])

    def kill(self, name: str) -> int:
        """SIGKILL one process; returns the wall time (ns) it was dead by."""
        self.processes[name].send_signal(signal.SIGKILL)
        self.processes[name].wait()
        return time.time_ns()

    def frame(self) -> int:
        return max((s.frame for s in self.tap.of(State)), default=-1)

    def finish(self, wait_until) -> tuple[Summary, object]:  # noqa: ANN001
        """Wait for the summary and every process to exit; returns it and the recording."""
        assert wait_until(lambda: self.tap.of(Summary), timeout=REALTIME_FRAMES / 30 + 15)
        for name, process in self.processes.items():
            assert process.wait(10) == 0, name
        return self.tap.of(Summary)[0], load(recording_path(self.directory, self.match))


@pytest.fixture
def live(bus, spawn, tap, tmp_path):
    return lambda match: LiveMatch(bus, spawn, tap, tmp_path, match)


def test_a_killed_agent_leaves_the_clock_alone_and_a_restarted_one_answers_within_1s(live, wait_until):
    match = live("agentkill")
    assert wait_until(lambda: match.frame() >= 60, timeout=20)
    killed = match.kill("shooter")
    assert wait_until(lambda: match.frame() >= 75)
    restarted = time.time_ns()
    match.start("shooter")
    summary, recording = match.finish(wait_until)

    assert summary.frame == REALTIME_FRAMES
    states = recording.states
    assert [s.frame for s in states] == list(range(REALTIME_FRAMES + 1)) and recording.gaps == []
    assert replay(recording) == []
    seconds = (states[-1].sent_ns - states[0].sent_ns) / 1e9
    assert seconds == pytest.approx(REALTIME_FRAMES / 30, rel=0.02)  # on time, no stall
    assert all(s.applied[1] == 0 for s in states if killed + 100e6 < s.sent_ns < restarted)
    answered = min(t for t, a in recording.actions if a.role == "shooter" and t > restarted)
    assert (answered - restarted) / 1e9 < 1.0


@pytest.mark.slow
@pytest.mark.long  # 8 s or more in the full run: kept out of the default run
def test_a_restarted_recorder_records_the_gap_it_missed_and_nothing_else(live, wait_until):
    match = live("reckill")
    assert wait_until(lambda: match.frame() >= 60, timeout=20)
    killed = match.kill("recorder")
    with recording_path(match.directory, match.match).open("ab") as log:
        log.write(b"\x40\0\0\0\1\2\3\4 torn")  # as if killed in the middle of a write
    assert wait_until(lambda: match.frame() >= 90)
    restarted = time.time_ns()
    match.start("recorder")
    summary, recording = match.finish(wait_until)

    assert summary.frame == REALTIME_FRAMES and recording.summary == summary and recording.clean
    frames = [s.frame for s in recording.states]
    assert len(frames) == len(set(frames)) and len(recording.gaps) == 1
    first, last = recording.gaps[0]
    assert sorted([*frames, *range(first, last + 1)]) == list(range(REALTIME_FRAMES + 1))
    # The gap holds what was published from about the kill until the restarted recorder was up.
    sent = {s.frame: s.sent_ns for s in match.tap.of(State)}
    assert killed - 100e6 < sent[first] and restarted < sent[last] < restarted + 1.5e9
