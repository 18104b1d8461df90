"""Self-play sweeps on the job system (services/jobs): the table's cells as jobs of kind `table`.

A worker gets up to `lanes` games at once (whole jobs), which it plays as the lanes of one batched
engine; the journal beside the table (OUT.journal) lets a stopped sweep resume from what it has.
The games are played by the pure core (table.py): results do not depend on which worker, or how
many, computed them.
"""

from __future__ import annotations

import threading
from pathlib import Path

from services.jobs.core import Spec, spec
from services.jobs.engine import open_engine
from services.jobs.kinds import Progress
from services.table.table import CHUNK, KINDS, LANES, Job, Table, assemble, jobs
from shared.bus import BusConfig


def journal_path(out: Path) -> Path:
    return out.with_name(out.name + ".journal")


def cell_spec(job: Job) -> Spec:
    """A table job as a job of the job system."""
    args = {"bait": job.bait, "shooter": job.shooter, "seeds": list(job.seeds)}
    return spec(job.id, "table", args, len(job.seeds))


def run_sweep(
    bus: BusConfig,
    sweep: str,
    out: Path,
    baits: list[str],
    shooters: list[str],
    games: int,
    chunk: int = CHUNK,
    progress: Progress | None = None,
    stop: threading.Event | None = None,
    job_timeout: float = 900.0,
    lanes: int = LANES,
    workers: int = 0,
    ray: str | None = None,
) -> Table | None:
    """Run a sweep until every job has a result, on the zenoh workers of `bus` (`workers` of them
    started here) or on the Ray cluster `ray`, then write the table to `out` (None if stopped
    first; the journal keeps what was collected). `progress` counts games."""
    cells = {cell_spec(job).id: job for job in jobs(baits, shooters, games, chunk)}
    todo = [cell_spec(job) for job in cells.values()]
    journal = journal_path(out)
    with open_engine(bus, sweep, journal, KINDS, workers, ray, stop, lanes // chunk, job_timeout) as engine:
        done = engine.run(todo, progress)
    if done is None:
        return None
    table = assemble(baits, shooters, games, {cells[k].id: v for k, v in done.items()}, chunk)
    out.parent.mkdir(parents=True, exist_ok=True)
    table.save(out)
    return table
