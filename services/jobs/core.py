"""The pure core of the job system, apart from the bus: jobs, who has which, and which results count.

Every bulk computation (a table's cells, an evaluation's games, sessions and identification runs)
is a list of `Spec`s handed out by one coordinator (services/jobs/bus.py). `Coordinator` keeps the
bookkeeping: jobs wait, go to idle live workers, come back when a worker dies, fails or runs past
a timeout, and only a job's first result counts. `check` is the one test every result passes
before it counts, whether it arrived from a worker or from a journal line written by an earlier run:
a known job, the library and rules hashes of this run, the number of values the job yields. The
journal (one JSON line per counted result) lets a stopped run resume from what it has.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

log = logging.getLogger("tsf.jobs")


@dataclass(frozen=True)
class Spec:
    """One job: its `kind` (shared.messages.JOB_KINDS), the kind's arguments, the plug-ins
    (`module:attr`) it needs imported, and `size`, the number of values its result must have."""

    id: str
    kind: str
    args: dict[str, Any]
    size: int
    plugins: tuple[str, ...] = ()


def spec(label: str, kind: str, args: dict[str, Any], size: int, plugins: tuple[str, ...] = ()) -> Spec:
    """A job whose id is `label` and a digest of what it computes: a journal line of one run can
    never stand in for a different job of another run with other options."""
    what = json.dumps([kind, args, sorted(plugins)], sort_keys=True, separators=(",", ":"))
    digest = hashlib.sha256(what.encode()).hexdigest()[:10]
    return Spec(f"{label[:50]}.{digest}", kind, args, size, tuple(plugins))


@dataclass(frozen=True)
class Hashes:
    """The library manifest and rules hashes a run computes with."""

    library: str
    config: str


def check(job: Spec | None, values: Any, library: str, config: str, ours: Hashes) -> str:
    """Why a result cannot count ("" when it can): unknown job, other library or rules, wrong size."""
    if job is None:
        return "no such job in this run"
    if (library, config) != (ours.library, ours.config):
        return f"computed with library/rules {library}/{config}, this run has {ours.library}/{ours.config}"
    if not isinstance(values, list) or len(values) != job.size:
        count = len(values) if isinstance(values, list) else type(values).__name__
        return f"{count} values, the job yields {job.size}"
    return ""


def journal_line(job: str, values: list, hashes: Hashes) -> str:
    record = {"job": job, "values": values, "library": hashes.library, "config": hashes.config}
    return json.dumps(record) + "\n"


@dataclass
class Journal:
    """What a journal holds for a run: counted results by job id, and the lines refused, with why."""

    done: dict[str, list] = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)


def read_journal(path: Path, jobs: dict[str, Spec], ours: Hashes) -> Journal:
    """The results an earlier run of the same jobs collected, each checked as a worker's result
    is; a torn line, or one of another library or rules, is refused (and said why); lines of jobs
    not in `jobs` (another run sharing the journal) are passed over."""
    out = Journal()
    if not path.exists():
        return out
    for number, line in enumerate(path.read_text().splitlines(), 1):
        try:
            record = json.loads(line)
            job, values = record["job"], record["values"]
            if job not in jobs:
                continue
            why = check(jobs.get(job), values, record["library"], record["config"], ours)
        except (json.JSONDecodeError, KeyError, TypeError) as error:
            why = f"unreadable ({type(error).__name__})"
        if why:
            out.refused.append(f"{path}:{number}: {why}")
        else:
            out.done.setdefault(job, values)
    return out


class JournalFile:
    """A run's journal, open for as long as the `with` block lasts, whichever engine runs the jobs:
    what earlier runs counted (`earlier`, each line checked as a result is) and each new counted
    result appended and flushed (`append`). A line torn by a killed run is ended on opening."""

    def __init__(self, path: Path, ours: Hashes) -> None:
        self.path, self.ours = path, ours

    def __enter__(self) -> JournalFile:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.file: TextIO = open(self.path, "a+")  # noqa: SIM115 - closed by __exit__
        self.file.seek(max(self.file.tell() - 1, 0))
        if self.file.read(1) not in ("", "\n"):
            self.file.write("\n")
        return self

    def __exit__(self, *exc: object) -> None:
        self.file.close()

    def earlier(self, jobs: dict[str, Spec]) -> dict[str, list]:
        """The counted results of `jobs` an earlier run left; refused lines are warned of once."""
        read = read_journal(self.path, jobs, self.ours)
        if read.refused:
            log.warning("%d journal lines refused, the first: %s", len(read.refused), read.refused[0])
        return read.done

    def append(self, job: str, values: list) -> None:
        self.file.write(journal_line(job, values, self.ours))
        self.file.flush()


class Coordinator:
    """Which jobs wait and which worker has which. An idle worker gets up to `per_worker` jobs at
    once (one per slot: a worker with slots runs one worker per slot), fewer when that would leave
    other idle workers without a share."""

    def __init__(self, todo: list[Spec], done: dict[str, list], per_worker: int = 1) -> None:
        self.jobs = {job.id: job for job in todo}
        self.done = {k: v for k, v in done.items() if k in self.jobs}
        self.waiting = [job for job in todo if job.id not in self.done]
        self.per_worker = max(per_worker, 1)
        self.flying: dict[str, dict[str, float]] = {}  # worker -> {job id: since}
        self.idle: set[str] = set()
        self.live: set[str] = set()
        self.barred: set[str] = set()  # workers that could not run a job: none of the sweep's again
        self.duplicates = 0
        self.failure = ""  # why the run cannot finish: a job that fails anywhere, or none will take it
        self.changed = threading.Condition()

    def worker_up(self, worker: str) -> None:
        with self.changed:
            if worker in self.barred:
                return
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
        self.waiting[:0] = [self.jobs[job] for job in ids if job not in {j.id for j in self.waiting}]

    def result(self, worker: str, job: str, values: list) -> bool:
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
        """A worker could not run a job (its library, rules or a plug-in differ, or its answer did
        not fit): its jobs go to others, and it gets no more of this run's."""
        with self.changed:
            mine = self.flying.pop(worker, {})
            self.live.discard(worker)
            self.idle.discard(worker)
            self.barred.add(worker)
            ids = [*mine, *([] if job in mine else [job])]
            self._requeue([j for j in ids if j in self.jobs and j not in self.done])
            self.changed.notify_all()

    def job_failed(self, worker: str, job: str, why: str) -> None:
        """A job failed for a reason that would fail again on any worker: the run ends with `why`."""
        with self.changed:
            self.flying.get(worker, {}).pop(job, None)
            self.failure = self.failure or f"job {job} failed on worker {worker}: {why}"
            self.changed.notify_all()

    def refused(self, worker: str, job: str, why: str) -> None:
        """A worker could not run a job (`failed`); if no live worker is left to take the waiting
        jobs, the run ends with `why` rather than wait for one that may never come."""
        self.failed(worker, job)
        with self.changed:
            if not self.live and not self.failure:
                self.failure = f"no live worker will take job {job}: worker {worker} said: {why}"
            self.changed.notify_all()

    def assignments(self, now: float, timeout: float) -> list[tuple[str, Spec]]:
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
