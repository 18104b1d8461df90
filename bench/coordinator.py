"""The job system's coordinator alone: jobs per second it hands out and counts when workers answer
at once (fake workers: zenoh sessions in this process that reply with valid values without playing),
the ceiling of any number of real workers. Real zenoh over loopback; the journal is written.

    .venv/bin/python bench/coordinator.py [--jobs 5000] [--workers 16,128] [--games 20]
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

from services.jobs.bus import Coordination
from services.jobs.core import spec
from services.jobs.kinds import hashes
from shared import keys
from shared.bus import BusConfig, free_endpoint, session, subscribe
from shared.messages import JobOrder, JobResult


def fake_worker(stack: ExitStack, endpoint: str, sweep: str, name: str, games: int) -> None:
    """A worker that answers every job at once with `games` zero values."""
    z = stack.enter_context(session(BusConfig("peer", (), (endpoint,))))
    ours = hashes()
    publisher = z.declare_publisher(keys.job_result(sweep))

    def answer(job: JobOrder) -> None:
        result = JobResult(
            sweep=sweep, frame=0, sender=f"worker/{name}", job=job.job, values=[0.0] * games,
            library=ours.library, config=ours.config,
        )  # fmt: skip
        publisher.put(result.encode())

    stack.enter_context(subscribe(z, keys.job_order(sweep, name), JobOrder, answer))
    stack.enter_context(z.liveliness().declare_token(keys.job_worker(sweep, name)))


def jobs_per_second(n_jobs: int, n_workers: int, games: int, journal: Path) -> float:
    endpoint, sweep = free_endpoint(), f"bench{n_workers}"
    todo = [
        spec(f"B1-S1-{i}", "table", {"bait": "B1", "shooter": "S1", "seeds": list(range(games))}, games)
        for i in range(n_jobs)
    ]
    bus = BusConfig("peer", (endpoint,), ())
    with Coordination(bus, sweep, journal, threading.Event()) as coordination, ExitStack() as stack:
        for i in range(n_workers):
            fake_worker(stack, endpoint, sweep, f"fake{i}", games)
        time.sleep(1.0)  # every token seen
        start = time.perf_counter()
        done = coordination.run(todo)
        took = time.perf_counter() - start
    assert done is not None and len(done) == n_jobs
    return n_jobs / took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=5000)
    parser.add_argument("--workers", default="16,128")
    parser.add_argument("--games", type=int, default=20, help="values per result (a table job's games)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(w) for w in args.workers.split(",")):
            rate = jobs_per_second(args.jobs, n, args.games, Path(tmp) / f"{n}.journal")
            print(
                f"coordinator, {n} fake workers, {args.jobs} jobs of {args.games} values: {rate:,.0f} jobs/s"
            )


if __name__ == "__main__":
    main()
