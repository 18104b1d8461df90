"""Headless engine speed: frames per second.

(a) the scalar engine alone, one core, fed pre-drawn uniform random actions (goal >= 20,000);
(b) the scalar engine with the two scripted policies, observations included;
(c) the batched engine alone, one core, random actions, at several batch sizes N (goal >= 1,000,000
    at the best N);
(d) batched self-play of two library network policies (B5 and S5: observations, inference,
    sampling), one process per core on 2 cores (goal >= 200,000).

Pin to cores for per-core figures, e.g. `taskset -c 1`. Run alone: other load skews every figure.

    .venv/bin/python bench/engine.py [--games N] [--lanes 256,1024,4096,16384]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import random
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from services.agent.scripted import CircleBait, MirrorShooter
from services.agent.seats import policy_for
from services.sim.batch import BatchGame
from services.sim.batch_play import play_batch
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


def batched(lanes: int, frames: int = 2_000_000) -> float:
    """The batched engine stepping `lanes` games with pre-drawn random actions, new games as they end."""
    batch = BatchGame(lanes)
    actions = np.random.default_rng(0).integers(0, 12, (64, 2, lanes))
    batch.step(actions[0, 0], actions[0, 1])  # compiled (or loaded from the cache) before timing
    done, start = 0, time.perf_counter()
    while done < frames:
        for bait, shooter in actions:
            if batch.done[0]:
                batch.reset(np.arange(lanes), np.arange(lanes) + done)
            batch.step(bait, shooter)
        done += 64 * lanes
    return done / (time.perf_counter() - start)


def self_play(games: int) -> int:
    """Frames of `games` batched B5 + S5 games, in one single-threaded process."""
    results = play_batch(policy_for("B5", "bait"), policy_for("S5", "shooter"), list(range(games)))
    return sum(r.frames for r in results)


def batched_self_play(games: int, cores: int = 2) -> float:
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # one core per process: BLAS threads would only contend
    with ProcessPoolExecutor(cores, mp_context=multiprocessing.get_context("spawn")) as pool:
        list(pool.map(self_play, [2] * cores))  # warm: imports, compiled loops
        start = time.perf_counter()
        frames = sum(pool.map(self_play, [games] * cores))
    return frames / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--games", type=int, default=20, help="one-minute games per measurement")
    parser.add_argument("--lanes", default="256,1024,4096,16384", help="batch sizes to try for (c)")
    args = parser.parse_args()
    print(f"(a) engine, random actions:    {random_actions(args.games):11,.0f} frames/s (goal >= 20,000)")
    print(f"(b) engine, scripted policies: {scripted(args.games):11,.0f} frames/s")
    fps, lanes = max((batched(int(n)), int(n)) for n in args.lanes.split(","))
    print(f"(c) batched engine, random actions, one core, best N={lanes}: {fps:,.0f} frames/s", end="")
    print(" (goal >= 1,000,000)")
    fps = batched_self_play(25 * args.games)
    print(f"(d) batched self-play B5 + S5, 2 cores: {fps:,.0f} frames/s (goal >= 200,000)")


if __name__ == "__main__":
    main()
