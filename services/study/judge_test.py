"""The study's judge in a process of its own: the same verdict as in the server's process, and a
worker that was killed is replaced without failing the trial it was judging."""

from __future__ import annotations

import os
import signal

from services.recorder.recording_test import record_match
from services.study.judge import Judge, judge


def test_the_judges_process_gives_the_verdict_and_survives_its_workers_death(tmp_path):
    path = tmp_path / "m.tsflog"
    record_match(path)
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
