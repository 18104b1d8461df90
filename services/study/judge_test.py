"""The study's judge in a process of its own: the same verdict as in the server's process, and a
worker that was killed is replaced without failing the trial it was judging, and one whose new
worker dies too (after its start, or at it) judges in the server's own process; either way, every
thread the judge started ends (a lost pool's thread deadlocked on CPython 3.13.0 and hung the exit)."""

from __future__ import annotations

import os
import signal
import threading
from concurrent.futures import ProcessPoolExecutor

import pytest

from services.recorder.recording_test import record_match
from services.study.judge import Judge, ask, judge


def assert_no_thread_left(before: set[threading.Thread]) -> None:
    for thread in set(threading.enumerate()) - before:
        thread.join(10)
        assert not thread.is_alive(), f"{thread} still runs after the judge closed"


def test_the_judges_process_gives_the_verdict_and_survives_its_workers_death(tmp_path):
    path = tmp_path / "m.tsflog"
    record_match(path)
    before = set(threading.enumerate())
    judging = Judge()
    try:
        here = judge(path, "bait")
        assert here[1] == ["no action of the participant's bait seat was recorded"]  # agents played it
        assert judging(path, "bait") == here
        assert judging(tmp_path / "gone.tsflog", "bait") == (None, ["no recording: no such file"])
        worker = judging.workers.submit(os.getpid).result()
        assert worker != os.getpid()
        os.kill(worker, signal.SIGKILL)
        assert judging(path, "bait") == here
        assert judging.workers.submit(os.getpid).result() not in (worker, os.getpid())
    finally:
        judging.close()
    assert_no_thread_left(before)


@pytest.mark.parametrize("at_start", [False, True], ids=["after-its-start", "at-its-start"])
def test_a_judge_whose_new_worker_dies_too_judges_in_the_servers_process(tmp_path, monkeypatch, at_start):
    path = tmp_path / "m.tsflog"
    record_match(path)
    before = set(threading.enumerate())
    judging = Judge()

    def doomed() -> ProcessPoolExecutor:
        """A new worker killed as soon as it has started (`at_start`: before its warm-up answers)."""
        workers = Judge._start()
        os.kill(workers.submit(os.getpid).result(), signal.SIGKILL)
        if at_start:
            ask(workers, int)  # BrokenProcessPool, as from a worker dying at its start
        return workers

    monkeypatch.setattr(judging, "_start", doomed)
    os.kill(judging.workers.submit(os.getpid).result(), signal.SIGKILL)
    try:
        assert judging(path, "shooter") == judge(path, "shooter")
    finally:
        judging.close()
    assert_no_thread_left(before)
