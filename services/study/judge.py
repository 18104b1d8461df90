"""A trial's judgement: its recording read back and checked, in a process of the server's own.

Reading a recording back decodes and checks every record (about 0.2 CPU-s for a minute of play).
In the server's process that work held the interpreter's lock while everyone else's frames, keys
and offers waited: when a dozen trials ended together, the next ones' Ready-to-first-frame p99
reached 113-171 ms in some runs, and each next offer waited for the judgements before it. The
`Judge` keeps one worker process, started with the server, that reads and judges; the server only
waits for its small answer (bench/study.py, 12 participants at once: Ready-to-first-frame p50
14-19 -> 2-4 ms).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TypeVar

from services.recorder.recording import Recording
from services.runtime.launch import read_recording
from shared.game import FPS
from shared.processes import end_with_parent

log = logging.getLogger("tsf.study")
T = TypeVar("T")
NICE = 5  # nice steps below the server: a judgement yields to the matches being played


def judge(path: Path, role: str) -> tuple[int | None, list[str]]:
    """A trial's recording read back from `path` and judged (verdict)."""
    return verdict(*read_recording(path), role)


def verdict(recording: Recording | None, problems: list[str], role: str) -> tuple[int | None, list[str]]:
    """A trial's recording as read (None: none), given what makes it less than a complete match
    (read_recording), judged: (kills, problems); no problems for a complete recording of the
    planned length with the participant's seat played from this server to its last second. The
    kills are the recording's, when it has a summary (a stopped match's sim still sends one)."""
    if recording is None:
        return None, [f"no recording: {'; '.join(problems)}"]
    problems = list(problems)
    answered = [a.frame for _, a in recording.actions if a.role == role and a.sender == f"human/{role}"]
    if not answered:
        problems.append(f"no action of the participant's {role} seat was recorded")
    elif recording.summary is not None and max(answered) < recording.summary.frame - FPS:
        last = f"frame {max(answered)} of {recording.summary.frame}"
        problems.append(f"the participant's {role} seat stopped answering at {last}")  # the page went
    return (recording.summary.kills if recording.summary else None), problems


class Judge:
    """`judge` in a worker process, started (and warmed) with the server, so that no interpreter
    starts while a study runs. Called from any thread; the caller waits for the answer. A worker
    that dies (killed) is replaced, and the judgement is asked of the new one (of the server's own
    process if that one dies too): a trial is never failed by its judge."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.workers = self._start()

    @staticmethod
    def _start() -> ProcessPoolExecutor:
        # Not fork: the server's threads (zenoh's, the gateway's) would be copied mid-step.
        workers = ProcessPoolExecutor(1, multiprocessing.get_context("spawn"), _worker)
        try:
            ask(workers, int)  # started now, not at the first trial's end
        except BaseException:  # a stop (KeyboardInterrupt) or a failure while it starts: none left
            workers.shutdown(cancel_futures=True)
            raise
        return workers

    def __call__(self, path: Path, role: str) -> tuple[int | None, list[str]]:
        workers = self.workers
        try:
            return ask(workers, judge, path, role)
        except BrokenProcessPool:
            pass
        try:
            return ask(self._replace(workers, path), judge, path, role)
        except BrokenProcessPool:  # lost again (or at its start): judged here, a moment of the others' time
            log.error("the judge's new process was lost too: %s is judged in the server's", path.name)
            return judge(path, role)

    def _replace(self, lost: ProcessPoolExecutor, path: Path) -> ProcessPoolExecutor:
        """A new worker in place of `lost`, once for all the threads that found it lost."""
        with self.lock:
            if self.workers is lost:
                log.warning("the judge's process was lost: a new one reads %s", path.name)
                self.workers = self._start()
            return self.workers

    def close(self) -> None:
        self.workers.shutdown()


def ask(workers: ProcessPoolExecutor, fn: Callable[..., T], *args: object) -> T:
    """`fn(*args)` in `workers`. A pool found broken is shut down before the error leaves: we hold it
    until its manager thread has ended, since that thread dropping the last reference while it
    breaks the pool deadlocks CPython 3.13.0 (gh-125451), and then the server at its exit."""
    try:
        return workers.submit(fn, *args).result()
    except BrokenProcessPool:
        workers.shutdown()
        raise


def _worker() -> None:
    """The worker yields to the matches being played, leaves a terminal's Ctrl-C (sent to the
    whole process group) to the server, which ends the study and then its judge, and ends at once
    when the server is gone however it went (a SIGKILLed server's worker ran on for hours)."""
    end_with_parent()
    os.nice(NICE)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
