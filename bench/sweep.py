"""Self-play sweep speed: frames per second of one worker, and the wall time of the full 9x7
table at N = 20 games (2.27 M frames) with 1 and 2 local workers over zenoh (process start
included; each worker plays up to --lanes games as one batch).
Goals: full table <= 20 s with 2 workers; 2 workers >= 1.8x one.

    .venv/bin/python bench/sweep.py [--games N] [--workers 1,2] [--lanes 640] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from services.agent import library
from services.jobs.bus import local_workers
from services.table.sweep import run_sweep
from services.table.table import LANES, jobs, run_jobs
from shared.bus import BusConfig, free_endpoint


def worker_fps(games: int = 4) -> float:
    """Frames per second of the in-process core on two rows of the table (learned baits with rule
    and learned shooters) played as one batch, as a worker plays its jobs."""
    todo = jobs(["B1", "B5"], library.keys("shooter"), games)
    start = time.perf_counter()
    run_jobs(todo)
    return len(todo) * games * 1800 / (time.perf_counter() - start)


def full_table(workers: int, games: int, out: Path, lanes: int) -> float:
    endpoint = free_endpoint()
    sweep = f"bench{workers}"
    bus = BusConfig("peer", (endpoint,), ())
    start = time.perf_counter()
    with local_workers(sweep, (endpoint,), workers):
        table = run_sweep(bus, sweep, out, library.keys("bait"), library.keys("shooter"), games, lanes=lanes)
    assert table is not None
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--games", type=int, default=20)
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--lanes", type=int, default=LANES, help="games a worker plays as one batch")
    parser.add_argument("--out", type=Path, default=None, help="Keep the tables here (default: a temp dir).")
    args = parser.parse_args()
    print(f"one worker, in-process: {worker_fps():,.0f} frames/s")
    frames = 9 * 7 * args.games * 1800
    walls = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        for n in (int(w) for w in args.workers.split(",")):
            walls[n] = full_table(n, args.games, out / f"table-{n}workers.json", args.lanes)
            print(f"full table, {n} worker(s): {walls[n]:.1f} s ({frames / walls[n]:,.0f} frames/s in all)")
    if 1 in walls and 2 in walls:
        print(f"speed-up of 2 workers over 1: {walls[1] / walls[2]:.2f}x")


if __name__ == "__main__":
    main()
