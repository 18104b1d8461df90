"""The job system over zenoh: one coordinator hands jobs to live workers, workers run them.

Workers announce themselves with liveliness tokens under tsf/sweep/<sweep>/worker/; the coordinator
(its bookkeeping is services/jobs/core.py) sends each idle worker its share on
tsf/sweep/<sweep>/job/<worker>, takes results on tsf/sweep/<sweep>/result, counts each job's first
result that passes `core.check`, appends it to the journal, and hands a dead, failed or late worker's
jobs to another. A worker exits when the coordinator it has seen goes away. Results depend on the
jobs only, never on which worker, or how many, computed them.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import zenoh

from services.jobs import kinds
from services.jobs.core import Coordinator, JournalFile, Spec, check
from services.jobs.kinds import Progress
from shared import keys
from shared.bus import BusConfig, Drops, free_endpoint, session, subscribe
from shared.errors import Failure, UsageError
from shared.messages import MAX_BYTES, JobOrder, JobResult, MessageError, decode, printable
from shared.processes import Processes

log = logging.getLogger("tsf.jobs")


class Coordination:
    """The coordinator of a sweep, for as long as the `with` block lasts: its token keeps the
    sweep's workers (which leave when it goes) through several runs of jobs (`run`), such as an
    evaluation's identification and team games. A worker barred for a job it could not run stays
    barred for the sweep."""

    def __init__(
        self, bus: BusConfig, sweep: str, journal: Path, stop: threading.Event | None = None,
        job_timeout: float = 900.0, per_worker: int = 1,
    ) -> None:  # fmt: skip
        self.bus, self.sweep, self.journal = bus, sweep, journal
        self.stop, self.job_timeout, self.per_worker = stop or threading.Event(), job_timeout, per_worker
        self.ours = kinds.hashes()
        self.state = Coordinator([], {})  # the run under way
        self.live: set[str] = set()
        self.barred: set[str] = set()
        self.lock = threading.Lock()
        self.drops = Drops(f"coordinator/{sweep}")

    def __enter__(self) -> Coordination:
        self._stack = ExitStack()
        self.z = self._stack.enter_context(session(self.bus))
        self.journal_file = self._stack.enter_context(JournalFile(self.journal, self.ours))
        sweep = self.sweep
        self._stack.enter_context(
            subscribe(self.z, keys.job_result(sweep), JobResult, self._result, self.drops)
        )
        self._stack.enter_context(
            self.z.liveliness().declare_subscriber(keys.job_worker(sweep), self._worker, history=True)
        )
        self._stack.enter_context(self.z.liveliness().declare_token(keys.job_coordinator(sweep)))
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def _worker(self, sample: zenoh.Sample) -> None:
        worker = keys.parse(sample.key_expr).worker
        with self.lock:
            up = sample.kind == zenoh.SampleKind.PUT
            (self.live.add if up else self.live.discard)(worker)
            state = self.state
        if up:
            log.info("worker %s is up", worker)
            state.worker_up(worker)
        else:
            state.worker_down(worker)

    def _result(self, result: JobResult) -> None:
        worker = result.sender.rsplit("/", 1)[-1]
        with self.lock:
            state = self.state
        if result.job not in state.jobs:
            raise MessageError("unknown_job", f"no job {result.job!r} in this run")
        if result.error and result.fault == "job":
            state.job_failed(worker, result.job, result.error)
            return
        if result.error:
            log.error("worker %s cannot run %s: %s; no more jobs", worker, result.job, result.error)
            self._bar(worker, result.job, result.error)
            return
        why = check(state.jobs[result.job], result.values, result.library, result.config, self.ours)
        if why:
            self._bar(worker, result.job, why)
            raise MessageError("mismatch", f"{worker}, job {result.job}: {why}")
        if state.result(worker, result.job, result.values):
            with self.lock:
                self.journal_file.append(result.job, result.values)

    def _bar(self, worker: str, job: str, why: str) -> None:
        with self.lock:
            self.barred.add(worker)
            state = self.state
        state.refused(worker, job, why)

    def _message(self, job: Spec) -> JobOrder:
        """The job as every worker receives it (`batch` set as it is sent). One that no worker would
        take (over the size limit, or breaking the job contract a worker checks) is a Failure here,
        before anything is sent, rather than a job that waits for its timeout."""
        message = JobOrder(
            sweep=self.sweep, frame=0, sender="coordinator", job=job.id, kind=job.kind, args=job.args,
            plugins=list(job.plugins), library=self.ours.library, config=self.ours.config,
            batch=self.per_worker,
        )  # fmt: skip
        data = message.encode()
        if len(data) > MAX_BYTES:
            raise Failure(f"job {job.id} is {len(data)} bytes, over {MAX_BYTES}: make the jobs smaller")
        try:
            decode(data, JobOrder)
        except MessageError as error:
            raise Failure(
                f"job {job.id} breaks the job contract, so no worker would run it: {error}"
            ) from None
        return message

    def run(self, todo: list[Spec], progress: Progress | None = None) -> dict[str, list] | None:
        """Hand out `todo` until every job has a result: the values by job id (None if stopped
        first; the journal keeps what was collected, and a run of the same jobs resumes from it)."""
        jobs = {job.id: job for job in todo}
        earlier = self.journal_file.earlier(jobs)
        messages = {job.id: self._message(job) for job in todo if job.id not in earlier}
        state = Coordinator(todo, earlier, self.per_worker)
        with self.lock:
            self.state, state.barred = state, set(self.barred)
            live = set(self.live)
        for worker in live:
            state.worker_up(worker)
        total = sum(job.size for job in todo)

        def report() -> None:
            if progress is not None:
                with state.changed:
                    progress(sum(jobs[j].size for j in state.done), total)

        while not state.finished and not self.stop.is_set():
            if state.failure:
                raise Failure(f"{state.failure} (the journal {self.journal} keeps the jobs done)")
            sent = state.assignments(time.monotonic(), self.job_timeout)
            batches = Counter(worker for worker, _ in sent)
            for worker, job in sent:
                message = dataclasses.replace(messages[job.id], batch=batches[worker])
                self.z.put(keys.job_order(self.sweep, worker), message.encode())
            report()
            with state.changed:
                state.changed.wait(0.5)
        report()
        return dict(state.done) if state.finished else None


@contextmanager
def with_local_workers(bus: BusConfig, sweep: str, local: int) -> Iterator[BusConfig]:
    """The coordinator's bus, with `local` worker processes started here for it (ended on exit),
    beside any worker reached through `bus` (a router given with --connect). With no local worker,
    a coordinator that neither connects nor listens at a port of its choosing could never be found:
    a UsageError."""
    if not local and not bus.connect and all(endpoint.endswith(":0") for endpoint in bus.listen):
        raise UsageError(
            "--workers", 0, "no worker could reach this coordinator: add --connect ROUTER or --listen"
        )
    if bus.mode == "client":  # the coordinator listens nowhere: local workers meet it at the router
        endpoints = bus.connect
    else:
        endpoints = (free_endpoint(),)
        bus = dataclasses.replace(bus, listen=(*bus.listen, *endpoints))
    with local_workers(sweep, endpoints, local):
        yield bus


@contextmanager
def local_workers(sweep: str, endpoints: tuple[str, ...], n: int) -> Iterator[list[subprocess.Popen]]:
    """`n` worker processes on this machine, connected to a coordinator (or router) at `endpoints`;
    ended on exit."""
    bus = BusConfig("peer", ("tcp/127.0.0.1:0",), endpoints)
    command = [sys.executable, "-m", "services.commands", "worker", *bus.to_args(), "--sweep", sweep]
    with Processes() as processes:
        yield [processes.start(f"worker{i}", [*command, "--id", f"{sweep}-local{i}"]) for i in range(n)]


def run_worker(
    bus: BusConfig, sweep: str, worker: str, runners: kinds.Kinds, stop: threading.Event | None = None
) -> int:
    """Run the jobs a sweep's coordinator sends this worker, each by its kind's runner in `runners`,
    until the coordinator goes away (or `stop`); returns
    the number of jobs done. A job it cannot run (other library or rules, a plug-in that does not
    import) is answered with the reason, and the coordinator sends it no more."""
    stop = stop or threading.Event()
    inbox: queue.Queue[JobOrder] = queue.Queue()
    drops = Drops(f"worker/{worker}")
    coordinator_seen = threading.Event()
    ours = kinds.hashes()
    done = 0
    with session(bus) as z:

        def on_coordinator(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                coordinator_seen.set()
            elif coordinator_seen.is_set():
                log.info("the coordinator of sweep %s is gone; worker %s stops", sweep, worker)
                stop.set()

        sender = f"worker/{worker}"
        publisher = z.declare_publisher(keys.job_result(sweep))

        def answer(job: JobOrder, values: list, error: str, fault: str, seconds: float) -> None:
            error = printable(error, 300)
            result = JobResult(
                sweep=sweep, frame=0, sender=sender, job=job.job, values=values, error=error,
                fault=fault if error else "", seconds=seconds, library=ours.library, config=ours.config,
            )  # fmt: skip
            publisher.put(result.encode())

        with (
            subscribe(z, keys.job_order(sweep, worker), JobOrder, inbox.put, drops),
            z.liveliness().declare_subscriber(keys.job_coordinator(sweep), on_coordinator, history=True),
            z.liveliness().declare_token(keys.job_worker(sweep, worker)),
        ):
            while not stop.is_set():
                try:
                    batch = [inbox.get(timeout=0.2)]
                except queue.Empty:
                    continue
                batch += _rest(inbox, batch[0].batch - 1)
                started = time.monotonic()
                fits = []
                for job in batch:
                    why = kinds.cannot_run(job.library, job.config, job.plugins, ours)
                    if why:
                        answer(job, [], why, "worker", 0.0)
                    else:
                        fits.append(job)
                for kind in dict.fromkeys(job.kind for job in fits):
                    mine = [job for job in fits if job.kind == kind]
                    played, why = _run(runners, kind, mine)
                    seconds = time.monotonic() - started
                    for job, values in zip(mine, played or [[]] * len(mine), strict=True):
                        answer(job, values, why, "job", seconds)
                    done += len(mine) if played else 0
    return done


def _run(runners: kinds.Kinds, kind: str, jobs: list[JobOrder]) -> tuple[list[list] | None, str]:
    """The jobs' values, or None and why they failed: the same jobs would fail on any worker, so
    the coordinator ends the run with that line (bad arguments end the run, not the worker)."""
    try:
        return kinds.run(runners, kind, [job.args for job in jobs]), ""
    except Exception as error:  # noqa: BLE001 - reported to the coordinator, which ends the run
        why = kinds.failure_line(error)
        log.error("%s jobs %s failed: %s", kind, [job.job for job in jobs], why)
        log.debug("the traceback", exc_info=True)
        return None, why


def _rest(inbox: queue.Queue[JobOrder], count: int, patience: float = 1.0) -> list[JobOrder]:
    """The rest of a batch: the `count` jobs the coordinator sent back to back with the first (or
    what came of them within `patience` seconds each: a lost message costs a wait, not the run)."""
    more = []
    while len(more) < count:
        try:
            more.append(inbox.get(timeout=patience))
        except queue.Empty:
            break
    return more
