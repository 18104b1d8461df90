"""Which engine a live sim runs: the scalar `Game` against the batched engine with one lane.

A live match starts one sim process, so its start-up counts as much as its frames:

(a) start-up: a fresh interpreter imports the engine and the observation, makes the game and
    gives its first two states (observations of both seats and the state hash), as a sim does
    before its first frame; numba's compiled loops come from its cache (`--cold`: from an empty
    cache, as after an edit of their sources or on a new machine);
(b) a live frame: one step, both seats' observations and the state hash, p50 and p99 over a
    one-minute game of random actions (the frame period is 33 ms).

    .venv/bin/python bench/live_engine.py [--runs 3] [--cold]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial

import numpy as np

FIRST_STATES = """
import time
start = time.perf_counter()
from services.sim.observation import observe
if {lanes}:
    import numpy as np
    from services.sim.batch import BatchGame
    game, step, state_hash = BatchGame(1, seeds=[3]), np.zeros(1, np.int64), lambda g: g.state_hash(0)
else:
    from services.sim.engine import Game
    game, step, state_hash = Game(seed=3), 0, lambda g: g.state_hash()
for frame in range(2):
    [observe(game, role) for role in ("bait", "shooter")]
    state_hash(game)
    game.step(step, step)
print(time.perf_counter() - start)
"""


def start_up(lanes: bool, cold: bool) -> float:
    """Seconds from a fresh interpreter's first import to the game's second state."""
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    with tempfile.TemporaryDirectory() as cache:
        if cold:
            env["NUMBA_CACHE_DIR"] = cache
        code = FIRST_STATES.format(lanes=lanes)
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
    return float(out.stdout)


def frames(lanes: bool) -> list[float]:
    """Microseconds per live frame (step, both observations, hash) over one game."""
    from services.sim.batch import BatchGame
    from services.sim.engine import Game
    from services.sim.observation import observe

    rng = random.Random(0)
    actions = [(rng.randrange(12), rng.randrange(12)) for _ in range(1800)]
    if lanes:
        game = BatchGame(1, seeds=[3])
        steps = [(np.array([a]), np.array([b])) for a, b in actions]
        observe(game, "bait")  # compiled (or loaded from the cache) before timing
        state_hash = partial(game.state_hash, 0)
    else:
        game, steps = Game(seed=3), actions
        state_hash = game.state_hash
    out = []
    for bait, shooter in steps:
        start = time.perf_counter_ns()
        game.step(bait, shooter)
        [observe(game, role) for role in ("bait", "shooter")]
        state_hash()
        out.append((time.perf_counter_ns() - start) / 1e3)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="fresh interpreters per engine for (a)")
    parser.add_argument("--cold", action="store_true", help="(a) from an empty numba cache")
    args = parser.parse_args()
    for name, lanes in (("Game", False), ("BatchGame(1)", True)):
        times = [start_up(lanes, args.cold) for _ in range(args.runs)]
        cache = "empty cache" if args.cold else "warm cache"
        print(
            f"(a) {name:13} start-up to the second state: median {statistics.median(times):.2f} s ({cache})"
        )
    for name, lanes in (("Game", False), ("BatchGame(1)", True)):
        us = frames(lanes)
        p99 = statistics.quantiles(us, n=100)[98]
        print(f"(b) {name:13} live frame: p50 {statistics.median(us):.0f} us, p99 {p99:.0f} us")


if __name__ == "__main__":
    main()
