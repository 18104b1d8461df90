"""The job system on Ray: a run's jobs as Ray tasks on a cluster a lab already runs (the `ray` extra).

The same jobs, runners, checks and journal as the zenoh workers (services/jobs/bus.py), only the
hand-out differs: each job is one Ray task, Ray places it, and Ray runs it again when its node is
lost (`max_retries`), so a lost node costs time, not results. A task never raises: it returns its
values or why it could not run, with whose fault that is, as a worker's `sweep_result` does; any
failure ends the run with that line (Ray nodes share one environment, so what fails on one would
fail on another). Every result passes `core.check` and becomes a journal line before it counts, so
a stopped run resumes from the journal whichever engine ran it, and the values are those of a
local run: pickled by Ray instead of msgpack, never rounded.
"""

from __future__ import annotations

import functools
import logging
import threading
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from services.jobs import kinds
from services.jobs.core import Hashes, JournalFile, Spec, check
from shared.errors import Failure, UsageError, install_line

RETRIES = 3  # a job's re-runs after its node or worker process is lost (Ray's max_retries)


@functools.cache
def _here() -> Hashes:
    """This Ray worker process's library and rules hashes, read once (a process serves many tasks)."""
    return kinds.hashes()


def _job(
    runners: kinds.Kinds, kind: str, args: dict[str, Any], plugins: list[str], ours: Hashes
) -> tuple[list, str, str, Hashes]:
    """One job on a Ray worker: (values, why not, whose fault, the hashes it computed with)."""
    here = _here()
    why = kinds.cannot_run(ours.library, ours.config, plugins, here)
    if why:
        return [], why, "worker", here
    try:
        return kinds.run(runners, kind, [args])[0], "", "", here
    except Exception as error:  # noqa: BLE001 - reported to the driver, which ends the run
        return [], kinds.failure_line(error), "job", here


REACH = 6.0  # seconds a cluster's address has to answer in: Ray's own client retries for minutes


def connect(ray: Any, address: str) -> None:
    """`ray.init` at `address`, or a Failure within REACH seconds: Ray retries an address where no
    cluster answers (nothing listens, a firewall drops it, another server answers) for minutes, so
    it waits in a thread of its own, left behind (a daemon) if it does not return in time."""
    done: list[BaseException | None] = []

    def init() -> None:
        try:
            ray.init(
                address=None if address == "local" else address,
                logging_level=logging.WARNING, log_to_driver=False, configure_logging=False,
            )  # fmt: skip
            done.append(None)
        except BaseException as error:  # noqa: BLE001 - handed to the caller's thread
            done.append(error)

    thread = threading.Thread(target=init, daemon=True, name="ray-init")
    thread.start()
    thread.join(None if address == "local" else REACH)  # a private cluster starts as long as it takes
    if not done:
        raise Failure(f"--ray {address}: no Ray cluster reached (no answer within {REACH:g} s)")
    if isinstance(done[0], (ConnectionError, RuntimeError, ValueError)):
        raise Failure(f"--ray {address}: no Ray cluster reached ({' '.join(str(done[0]).split())[:200]})")
    if done[0] is not None:
        raise done[0]


class OnRay:
    """A run's engine on the Ray cluster at `address` (`auto`, `HOST:PORT`, `ray://HOST:10001`, or
    `local` for a private one on this machine) for as long as the `with` block lasts; `run` has
    the signature of bus.Coordination.run."""

    def __init__(
        self, address: str, journal: Path, runners: kinds.Kinds, stop: threading.Event | None = None
    ) -> None:
        self.address, self.journal, self.stop = address, journal, stop or threading.Event()
        self.runners = dict(runners)

    def __enter__(self) -> OnRay:
        try:
            import ray
        except ModuleNotFoundError:
            raise UsageError("--ray", self.address, f"needs the `ray` extra: {install_line('ray')}") from None
        self.ray, self.ours = ray, kinds.hashes()
        connect(ray, self.address)
        self._stack = ExitStack()
        self._stack.callback(ray.shutdown)
        self.journal_file = self._stack.enter_context(JournalFile(self.journal, self.ours))
        self.task = ray.remote(num_cpus=1, max_retries=RETRIES, retry_exceptions=False)(_job)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def run(self, todo: list[Spec], progress: kinds.Progress | None = None) -> dict[str, list] | None:
        """Every job of `todo` not in the journal as a Ray task, until each has a counted result: the
        values by job id (None if stopped first; the journal keeps what was collected)."""
        jobs = {job.id: job for job in todo}
        done = self.journal_file.earlier(jobs)
        flying = {
            self.task.remote(self.runners, job.kind, job.args, list(job.plugins), self.ours): job
            for job in todo
            if job.id not in done
        }
        total = sum(job.size for job in todo)
        try:
            while flying and not self.stop.is_set():
                if progress is not None:
                    progress(sum(jobs[j].size for j in done), total)
                ready, _ = self.ray.wait(list(flying), num_returns=len(flying), timeout=0.5)
                for ref in ready:
                    job = flying.pop(ref)
                    values, why, fault, theirs = self._get(ref, job)
                    if why:
                        raise Failure(
                            f"job {job.id} failed on Ray ({fault}): {why} "
                            f"(the journal {self.journal} keeps the jobs done)"
                        )
                    refused = check(job, values, theirs.library, theirs.config, self.ours)
                    if refused:
                        raise Failure(f"job {job.id}: {refused}")
                    done[job.id] = values
                    self.journal_file.append(job.id, values)
        finally:
            for ref in flying:
                self.ray.cancel(ref, force=True)
        if progress is not None:
            progress(sum(jobs[j].size for j in done), total)
        return None if flying else done

    def _get(self, ref: object, job: Spec) -> tuple[list, str, str, Hashes]:
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayError as error:  # retries spent: its nodes were lost, say
            first = (str(error).strip().splitlines() or [type(error).__name__])[0]
            raise Failure(f"job {job.id} was lost on Ray after {RETRIES} retries: {first[:200]}") from None
