"""Self-play sweep speed: frames per second of one worker, the wall time of the full 9x7 table at
N = 20 games (2.27 M frames) with 1 and 2 workers on each engine (zenoh: local worker processes,
process start included, each playing up to --lanes games as one batch; Ray: a local cluster of
that many CPUs started first, one task per job), and each engine's overhead per job (a run of
40 one-game jobs on one worker, minus the same jobs in-process).
Goals: full table <= 20 s with 2 workers; 2 workers >= 1.8x one, on each engine.

    .venv/bin/python bench/sweep.py [--games N] [--workers 1,2] [--lanes 640] [--engines zenoh,ray]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from services.agent import library
from services.jobs.bus import local_workers
from services.jobs.core import spec
from services.jobs.engine import open_engine
from services.jobs.kinds import in_process
from services.table.sweep import cell_spec, run_sweep
from services.table.table import KINDS, LANES, jobs, run_jobs
from shared.bus import BusConfig, free_endpoint


def worker_fps(games: int = 4) -> float:
    """Frames per second of the in-process core on two rows of the table (learned baits with rule
    and learned shooters) played as one batch, as a worker plays its jobs."""
    todo = jobs(["B1", "B5"], library.keys("shooter"), games)
    start = time.perf_counter()
    run_jobs(todo)
    return len(todo) * games * 1800 / (time.perf_counter() - start)


@contextmanager
def ray_cluster(cpus: int) -> Iterator[str]:
    """The address of a local Ray cluster of `cpus` CPUs (one node), shut down on exit."""
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": cpus})
    try:
        yield cluster.address
    finally:
        cluster.shutdown()


def full_table(engine: str, workers: int, games: int, out: Path, lanes: int) -> float:
    """Seconds to the full table on `workers` workers of `engine` (zenoh: their start included)."""
    endpoint = free_endpoint()
    sweep = f"bench{workers}"
    bus = BusConfig("peer", (endpoint,), ())
    keys = library.keys("bait"), library.keys("shooter")
    if engine == "ray":
        with ray_cluster(workers) as address:
            start = time.perf_counter()
            table = run_sweep(bus, sweep, out, *keys, games, lanes=lanes, ray=address)
    else:
        start = time.perf_counter()
        with local_workers(sweep, (endpoint,), workers):
            table = run_sweep(bus, sweep, out, *keys, games, lanes=lanes)
    assert table is not None
    return time.perf_counter() - start


def per_job(engine: str, out: Path, n: int = 40) -> tuple[float, float]:
    """Seconds per job of n one-game jobs on one worker of `engine` and in-process (the worker
    warm, its imports and caches loaded by a first run): the difference is the engine's overhead."""
    todo = [cell_spec(job) for job in jobs(["B4", "B7"], ["S4", "S5"], n // 4, 1)]
    here = in_process(KINDS)
    here(todo[:4])
    start = time.perf_counter()
    here(todo)
    alone = time.perf_counter() - start
    endpoint = free_endpoint()
    bus = BusConfig("peer", (endpoint,), ())
    with ExitStack() as stack:
        ray = stack.enter_context(ray_cluster(1)) if engine == "ray" else None
        if ray is None:
            stack.enter_context(local_workers("overhead", (endpoint,), 1))
        engine_run = stack.enter_context(
            open_engine(bus, "overhead", out / f"{engine}.journal", KINDS, 0, ray)
        )
        warm = [spec("warm", "table", {"bait": "B1", "shooter": "S1", "seeds": [0]}, 1)]
        engine_run.run(warm)
        start = time.perf_counter()
        engine_run.run(todo)
        return (time.perf_counter() - start) / n, alone / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--games", type=int, default=20)
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--lanes", type=int, default=LANES, help="games a worker plays as one batch")
    parser.add_argument("--engines", default="zenoh,ray", help="zenoh, ray or both")
    parser.add_argument("--out", type=Path, default=None, help="Keep the tables here (default: a temp dir).")
    args = parser.parse_args()
    print(f"one worker, in-process: {worker_fps():,.0f} frames/s")
    frames = 9 * 7 * args.games * 1800
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        for engine in args.engines.split(","):
            walls = {}
            for n in (int(w) for w in args.workers.split(",")):
                walls[n] = full_table(engine, n, args.games, out / f"table-{engine}-{n}.json", args.lanes)
                rate = frames / walls[n]
                print(f"{engine}: full table, {n} worker(s): {walls[n]:.1f} s ({rate:,.0f} frames/s)")
            if 1 in walls and 2 in walls:
                print(f"{engine}: speed-up of 2 workers over 1: {walls[1] / walls[2]:.2f}x")
            there, here = per_job(engine, out)
            print(
                f"{engine}: one-game jobs on one worker {there * 1e3:.1f} ms each, in-process "
                f"{here * 1e3:.1f} ms: overhead per job {(there - here) * 1e3:.1f} ms"
            )


if __name__ == "__main__":
    main()
