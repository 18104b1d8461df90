"""Headless engine speed on one core: frames per second.

(a) the engine alone, fed pre-drawn uniform random actions (goal: >= 20,000 frames/s);
(b) the engine with the two scripted policies, observations included.

    .venv/bin/python bench/engine.py [--games N]
"""

from __future__ import annotations

import argparse
import random
import time

from services.agent.scripted import CircleBait, MirrorShooter
from services.sim.engine import Game
from services.sim.observation import observe


def random_actions(games: int) -> float:
    rng = random.Random(0)
    streams = [[(rng.randrange(12), rng.randrange(12)) for _ in range(1800)] for _ in range(games)]
    frames = 0
    start = time.perf_counter()
    for seed, stream in enumerate(streams):
        game = Game(seed=seed)
        step = game.step
        for bait_action, shooter_action in stream:
            step(bait_action, shooter_action)
        frames += game.frame
    return frames / (time.perf_counter() - start)


def scripted(games: int) -> float:
    frames = 0
    start = time.perf_counter()
    for seed in range(games):
        game, bait, shooter = Game(seed=seed), CircleBait(), MirrorShooter()
        bait.reset(seed)
        shooter.reset(seed + 1)
        while not game.done:
            game.step(bait.act(observe(game, "bait")), shooter.act(observe(game, "shooter")))
        frames += game.frame
    return frames / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--games", type=int, default=20, help="one-minute games per measurement")
    args = parser.parse_args()
    print(f"(a) engine, random actions:    {random_actions(args.games):9,.0f} frames/s (goal >= 20,000)")
    print(f"(b) engine, scripted policies: {scripted(args.games):9,.0f} frames/s")


if __name__ == "__main__":
    main()
