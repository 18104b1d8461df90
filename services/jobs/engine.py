"""Which engine a run's jobs go to: the project's own coordinator and workers over zenoh
(services/jobs/bus.py), or a Ray cluster (services/jobs/ray_engine.py, the `ray` extra). Both
take the same jobs, check every result the same way and keep the same journal, so a run's numbers,
and its resume, do not depend on the engine (docs/jobs.md: when to pick which)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol

from services.jobs.bus import Coordination, with_local_workers
from services.jobs.core import Spec
from services.jobs.kinds import Kinds, Progress, Runner
from services.jobs.ray_engine import OnRay
from shared.bus import BusConfig
from shared.errors import Failure


class Engine(Protocol):
    journal: Path

    def run(self, todo: list[Spec], progress: Progress | None = None) -> dict[str, list] | None: ...


def on_workers(engine: Engine) -> Runner:
    """A runner (services/jobs/kinds.py) that hands its jobs to the engine's workers; a stopped
    run is a Failure (the journal keeps what was collected)."""

    def run(todo: list[Spec], progress: Progress | None = None) -> list[list]:
        done = engine.run(todo, progress)
        if done is None:
            raise Failure(f"stopped; run the same command again to resume from {engine.journal}")
        return [done[job.id] for job in todo]

    return run


@contextmanager
def open_engine(
    bus: BusConfig,
    sweep: str,
    journal: Path,
    runners: Kinds,
    workers: int = 0,
    ray: str | None = None,
    stop: threading.Event | None = None,
    per_worker: int = 1,
    job_timeout: float = 900.0,
) -> Iterator[Engine]:
    """The Ray cluster at `ray` when one is named, its tasks run by `runners`; else a zenoh
    coordinator on `bus` for `sweep`, with `workers` local worker processes (`tsf worker`, ended on
    exit) beside any reached through the bus."""
    if ray:
        with OnRay(ray, journal, runners, stop) as engine:
            yield engine
        return
    with (
        with_local_workers(bus, sweep, workers) as coordinator_bus,
        Coordination(coordinator_bus, sweep, journal, stop, job_timeout, per_worker) as coordination,
    ):
        yield coordination
