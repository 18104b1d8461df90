"""Distributed self-play sweeps over zenoh: a coordinator hands table jobs to live workers.

Workers announce themselves with liveliness tokens; the coordinator keeps a batch of jobs in flight
per live worker (up to `lanes` games, which the worker plays as the lanes of one batched engine),
hands a dead worker's jobs to another, counts each job's first result only, and
appends every result to a journal beside the table, so that a stopped sweep resumes from what it
has. A worker exits when the coordinator it has seen goes away. The games themselves are played
by the pure core (table.py): results do not depend on which worker, or how many, computed them.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from services.agent import library
from services.processes import Processes
from services.table.table import CHUNK, LANES, Job, Table, assemble, jobs, run_jobs
from shared import keys
from shared.bus import BusConfig, Drops, session, subscribe
from shared.game import GameConfig
from shared.messages import MessageError, SweepJob, SweepResult

log = logging.getLogger("tsf.sweep")
Progress = Callable[[int, int], None]  # (jobs done, jobs in all)


def journal_path(out: Path) -> Path:
    return out.with_name(out.name + ".journal")


def read_journal(path: Path) -> dict[str, list[float]]:
    """Results already collected by an earlier run of the same sweep (a torn last line is skipped)."""
    done: dict[str, list[float]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            done.setdefault(record["job"], record["kills_per_minute"])
    return done


class Coordinator:
    """The bookkeeping of a sweep, apart from the bus: which jobs wait, which worker has which.
    An idle worker gets up to `per_worker` jobs at once, fewer when that would leave other idle
    workers without a share."""

    def __init__(self, todo: list[Job], done: dict[str, list[float]], per_worker: int = 1) -> None:
        self.jobs = {job.id: job for job in todo}
        self.done = {k: v for k, v in done.items() if k in self.jobs}
        self.waiting = [job for job in todo if job.id not in self.done]
        self.per_worker = max(per_worker, 1)
        self.flying: dict[str, dict[str, float]] = {}  # worker -> {job id: since}
        self.idle: set[str] = set()
        self.live: set[str] = set()
        self.duplicates = 0
        self.changed = threading.Condition()

    def worker_up(self, worker: str) -> None:
        with self.changed:
            self.live.add(worker)
            if worker not in self.flying:
                self.idle.add(worker)
            self.changed.notify_all()

    def worker_down(self, worker: str) -> None:
        with self.changed:
            self.live.discard(worker)
            self.idle.discard(worker)
            left = [job for job in self.flying.pop(worker, {}) if job not in self.done]
            if left:
                log.warning("worker %s left with jobs %s; handing them to another", worker, left)
                self._requeue(left)
            self.changed.notify_all()

    def _requeue(self, ids: list[str]) -> None:
        self.waiting[:0] = [self.jobs[job] for job in ids]

    def result(self, worker: str, job: str, values: list[float]) -> bool:
        """Record a job's result; False for a duplicate (a job counts once)."""
        with self.changed:
            if job in self.flying.get(worker, {}):
                del self.flying[worker][job]
                if not self.flying[worker]:
                    del self.flying[worker]
            if worker in self.live and worker not in self.flying:
                self.idle.add(worker)
            fresh = job in self.jobs and job not in self.done
            if fresh:
                self.done[job] = values
                self.waiting = [j for j in self.waiting if j.id != job]
            else:
                self.duplicates += 1
            self.changed.notify_all()
            return fresh

    def failed(self, worker: str, job: str) -> None:
        """A worker could not run a job (its library or rules differ): give it nothing more."""
        with self.changed:
            mine = self.flying.pop(worker, {})
            self.live.discard(worker)
            self.idle.discard(worker)
            ids = [*mine, *([] if job in mine else [job])]
            self._requeue([j for j in ids if j in self.jobs and j not in self.done])
            self.changed.notify_all()

    def assignments(self, now: float, timeout: float) -> list[tuple[str, Job]]:
        """Jobs to send now: a batch per idle worker; a job in flight past `timeout` is sent again."""
        with self.changed:
            for worker, mine in list(self.flying.items()):
                late = [job for job, since in mine.items() if now - since > timeout and job not in self.done]
                if late:
                    log.warning(
                        "jobs %s on %s took over %.0f s; handing them to another", late, worker, timeout
                    )
                    del self.flying[worker]
                    self._requeue(late)
            out = []
            while self.idle and self.waiting:
                worker = min(self.idle)
                share = min(self.per_worker, math.ceil(len(self.waiting) / len(self.idle)))
                batch, self.waiting = self.waiting[:share], self.waiting[share:]
                self.idle.discard(worker)
                self.flying[worker] = {job.id: now for job in batch}
                out += [(worker, job) for job in batch]
            return out

    @property
    def finished(self) -> bool:
        return len(self.done) == len(self.jobs)


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
) -> Table | None:
    """Coordinate a sweep until every job has a result, then write the table to `out` (None if
    stopped first; the journal keeps what was collected). A worker gets up to `lanes` games at a
    time (whole jobs, at least one)."""
    stop = stop or threading.Event()
    todo = jobs(baits, shooters, games, chunk)
    journal = journal_path(out)
    state = Coordinator(todo, read_journal(journal), lanes // chunk)
    library_hash, config_hash = library.manifest_hash(), GameConfig().hash()
    drops = Drops("sweep")
    journal_lock = threading.Lock()
    out.parent.mkdir(parents=True, exist_ok=True)
    with session(bus) as z, open(journal, "a") as journal_file:

        def on_worker(sample: zenoh.Sample) -> None:
            worker = keys.parse(sample.key_expr).worker
            if sample.kind == zenoh.SampleKind.PUT:
                log.info("worker %s is up", worker)
                state.worker_up(worker)
            else:
                state.worker_down(worker)

        def on_result(result: SweepResult) -> None:
            if result.job not in state.jobs:
                raise MessageError("unknown_job", f"no job {result.job!r} in this sweep")
            worker = result.sender.rsplit("/", 1)[-1]
            if result.error:
                log.error("worker %s cannot run %s: %s", worker, result.job, result.error)
                state.failed(worker, result.job)
            elif len(result.kills_per_minute) != len(state.jobs[result.job].seeds):
                drops.drop(
                    keys.sweep_result(sweep), MessageError("shape", f"{result.job}: wrong number of games")
                )
                state.failed(worker, result.job)
            elif state.result(worker, result.job, result.kills_per_minute):
                record = {"job": result.job, "kills_per_minute": result.kills_per_minute}
                with journal_lock:
                    journal_file.write(json.dumps(record) + "\n")
                    journal_file.flush()

        with (
            subscribe(z, keys.sweep_result(sweep), SweepResult, on_result, drops),
            z.liveliness().declare_subscriber(keys.sweep_worker(sweep), on_worker, history=True),
            z.liveliness().declare_token(keys.sweep_coordinator(sweep)),
        ):
            while not state.finished and not stop.is_set():
                for worker, job in state.assignments(time.monotonic(), job_timeout):
                    seeds = list(job.seeds)
                    message = SweepJob(
                        match=sweep,
                        frame=0,
                        sender="sweep",
                        job=job.id,
                        bait=job.bait,
                        shooter=job.shooter,
                        seeds=seeds,
                        library=library_hash,
                        config=config_hash,
                    )
                    z.put(keys.sweep_job(sweep, worker), message.encode())
                if progress is not None:
                    progress(len(state.done), len(state.jobs))
                with state.changed:
                    state.changed.wait(0.5)
    if progress is not None:
        progress(len(state.done), len(state.jobs))
    if not state.finished:
        return None
    table = assemble(baits, shooters, games, state.done, chunk)
    table.save(out)
    return table


@contextmanager
def local_workers(sweep: str, endpoint: str, n: int) -> Iterator[list[subprocess.Popen]]:
    """`n` worker processes on this machine, connected to a coordinator listening on `endpoint`;
    ended on exit."""
    bus = BusConfig("peer", ("tcp/127.0.0.1:0",), (endpoint,))
    command = [sys.executable, "-m", "services.cli", "worker", *bus.to_args(), "--sweep", sweep]
    with Processes() as processes:
        yield [processes.start(f"worker{i}", [*command, "--id", f"{sweep}-local{i}"]) for i in range(n)]


def run_worker(bus: BusConfig, sweep: str, worker: str, stop: threading.Event | None = None) -> int:
    """Run the jobs a sweep's coordinator sends this worker until it goes away (or `stop`); returns
    the number of jobs done."""
    stop = stop or threading.Event()
    inbox: queue.Queue[SweepJob] = queue.Queue()
    drops = Drops(f"worker/{worker}")
    coordinator_seen = threading.Event()
    library_hash, config_hash = library.manifest_hash(), GameConfig().hash()
    done = 0
    with session(bus) as z:

        def on_coordinator(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                coordinator_seen.set()
            elif coordinator_seen.is_set():
                log.info("the coordinator of sweep %s is gone; worker %s stops", sweep, worker)
                stop.set()

        sender = f"worker/{worker}"
        publisher = z.declare_publisher(keys.sweep_result(sweep))
        with (
            subscribe(z, keys.sweep_job(sweep, worker), SweepJob, inbox.put, drops),
            z.liveliness().declare_subscriber(keys.sweep_coordinator(sweep), on_coordinator, history=True),
            z.liveliness().declare_token(keys.sweep_worker(sweep, worker)),
        ):
            while not stop.is_set():
                try:
                    batch = [inbox.get(timeout=0.2)]
                except queue.Empty:
                    continue
                batch += _drain(inbox)
                started = time.monotonic()
                fits = [job for job in batch if (job.library, job.config) == (library_hash, config_hash)]
                error = (
                    f"library/rules {library_hash}/{config_hash} here, {{}} in the sweep: update this "
                    "worker's checkout"
                )
                answers = [
                    (job, [], error.format(f"{job.library}/{job.config}")) for job in batch if job not in fits
                ]
                if fits:
                    played = run_jobs([Job(job.bait, job.shooter, tuple(job.seeds)) for job in fits])
                    answers += [(job, values, "") for job, values in zip(fits, played, strict=True)]
                seconds = time.monotonic() - started
                for job, values, why in answers:
                    result = SweepResult(
                        match=sweep, frame=0, sender=sender, job=job.job, kills_per_minute=values, error=why,
                        seconds=seconds,
                    )  # fmt: skip
                    publisher.put(result.encode())
                done += len(fits)
    return done


def _drain(inbox: queue.Queue[SweepJob], quiet: float = 0.05) -> list[SweepJob]:
    """The rest of a batch: the coordinator sends a worker's jobs back to back, so whatever
    arrives until the inbox has been quiet for `quiet` seconds."""
    more = []
    while True:
        try:
            more.append(inbox.get(timeout=quiet))
        except queue.Empty:
            return more
