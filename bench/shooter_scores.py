"""Shooters of a library of one's own beside the shipped ones of the same keys: kills/min (± s.e.)
with every shipped bait on the table's seeds (0-19, so the shipped rows are the table's), and how
fast each shooter moves (mean px/frame over the frames it is alive), how often it dies (per game,
by cause) and fires. docs/library.md compares the speed-cap try of S1-S3 with it.

    .venv/bin/python bench/shooter_scores.py DIR S1 [S2 ...] [--games 20]
"""

from __future__ import annotations

import argparse
from functools import cache, partial
from pathlib import Path

import numpy as np

from services.agent import library, networks
from services.sim.batch import BatchGame
from services.sim.batch_play import RoleLanes, results
from services.sim.observation import observe
from services.sim.play import summarize


def scores(shooter, baits: list[str], games: int) -> tuple[list, float, list]:  # noqa: ANN001 - a Policy
    """(each bait's Summary, the shooter's mean speed, every game's result): one batch, a lane per
    bait and seed."""
    seeds = list(range(games)) * len(baits)
    bait_of = np.repeat(np.arange(len(baits)), games)
    batch = BatchGame(len(seeds), None, seeds)
    seats = [
        RoleLanes("bait", [networks.load(b) for b in baits], bait_of, seeds),
        RoleLanes("shooter", [shooter], np.zeros(len(seeds), np.int64), seeds),
    ]
    moved, frames = 0.0, 0
    while not batch.done[0]:
        frame = int(batch.state.frame[0])
        batch.step(*(seat.act(cache(partial(observe, batch, seat.role)), frame) for seat in seats))
        s, alive = batch.state, batch.state.alive[:, 1]
        moved += float(np.hypot(s.vx[alive, 1], s.vy[alive, 1]).sum())
        frames += int(alive.sum())
    played = results(batch, seeds)
    summaries = [summarize(played[i * games : (i + 1) * games]) for i in range(len(baits))]
    return summaries, moved / max(frames, 1), played


def habits(played: list) -> str:
    """The shooter's deaths per game by cause and missiles fired per game."""
    shooter = [r.counters["shooter"] for r in played]
    deaths = {cause: sum(c["deaths"][cause] for c in shooter) / len(played) for cause in shooter[0]["deaths"]}
    fired = sum(c["missiles_fired"] for c in shooter) / len(played)
    return ", ".join([*(f"{cause} {n:.1f}" for cause, n in deaths.items()), f"fired {fired:.1f}"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("library", type=Path, help="the library the tried shooters were trained into")
    parser.add_argument("keys", nargs="+", help="shooter keys")
    parser.add_argument("--games", type=int, default=20)
    args = parser.parse_args()
    baits = library.keys("bait")
    print(f"| shooter | library | speed px/frame | {' | '.join(baits)} | best | its deaths, shots a game |")
    print(f"| --- | --- | --- | {' | '.join('---' for _ in baits)} | --- | --- |")
    for key in args.keys:
        for name, root in (("shipped", library.LIBRARY), ("tried", args.library)):
            summaries, speed, played = scores(networks.load(key, root=root), baits, args.games)
            cells = [f"{s.mean:.2f} ± {s.stderr:.2f}" for s in summaries]
            best = max(range(len(baits)), key=lambda i: summaries[i].mean)
            cells.append(f"{baits[best]} {summaries[best].mean:.2f}")
            print(f"| {key} | {name} | {speed:.2f} | {' | '.join(cells)} | {habits(played)} |")


if __name__ == "__main__":
    main()
