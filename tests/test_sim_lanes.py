"""A pool's matches are lanes of one batched engine (services/sim/lanes.py): a match records the same
whether it plays alone (a pool of one lane) or among matches that start and end at other frames
(their lanes taken, grown and freed around it), and the same as the scalar engine recorded it
before the pool played lanes."""

from __future__ import annotations

import dataclasses
import hashlib
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgpack

from services.population.seat import SeatSpec
from services.recorder.recording import Recording, load, replay
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool

# The content digest of this seeded lockstep match as the pool recorded it with a `Game` per match
# (commit b901a08, before lanes): each recording below must have the very same content.
BEFORE = "1b0aad48cec545a6"
FRAMES = 90


def plan(
    match: str, directory: Path, frames: int = FRAMES, mode: str = "lockstep", seed: int = 7
) -> MatchPlan:
    seats = {"bait": SeatSpec.parse("B5"), "shooter": SeatSpec.parse("S5")}
    return MatchPlan(match, seed=seed, frames=frames, mode=mode, directory=directory, timeout=60, **seats)


def content(recording: Recording) -> str:
    """A digest of what a recording says of its match, less what differs from run to run: its id,
    the times (a state's sent_ns, the actions' arrival, the summary's timing) and the order in which
    the two seats' answers to a state arrived."""

    def same(message: object, **fields: object) -> bytes:
        return dataclasses.replace(message, match="m", **fields).encode()

    parts = [
        same(recording.start),
        *(same(state, sent_ns=0) for state in recording.states),
        *sorted(same(action) for _, action in recording.actions),
        *(same(event) for event in recording.events),
        same(recording.summary, timing={}),
    ]
    return hashlib.blake2b(msgpack.packb(parts), digest_size=8).hexdigest()


def test_a_match_records_the_same_alone_among_other_lanes_and_as_before(tmp_path: Path) -> None:
    with Pool("lanes", tmp_path, adaptive=False) as pool:
        alone = load(pool.run(plan("alone", tmp_path)).path)
        others = [plan(f"other-{n}", tmp_path, 30 + 40 * n, "realtime", seed=n) for n in range(3)]
        with ThreadPoolExecutor(len(others) + 1) as threads:
            played = [threads.submit(pool.run, other) for other in others]
            time.sleep(0.5)  # the others are under way: the match starts at other frames than theirs
            among = load(pool.run(plan("among", tmp_path)).path)
            assert all(p.result().summary.frame == o.frames for p, o in zip(played, others, strict=True))
    for recording in (alone, among):
        assert recording.problems() == [] and replay(recording) == []  # the scalar engine agrees
        assert len(recording.states) == FRAMES + 1
    assert content(alone) == content(among) == BEFORE
