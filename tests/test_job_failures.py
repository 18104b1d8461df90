"""A mistake inside a job ends the run at once, with one line and an exit status (issue: jobs that
fail, fail at once). Real `tsf eval` processes with a real local worker over zenoh: what the
coordinator can check before any worker starts is exit 2 within seconds; what fails mid-game in a
worker is exit 1 naming the job, partner, seed and error; a job no live worker takes fails too."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid

import pytest

from services.jobs.bus import Coordination
from services.jobs.core import Coordinator, spec
from services.jobs.engine import on_workers
from shared.errors import Failure

LAB = '''
from services.population.partners_test import Constant

class Late(Constant):
    """Plays for 100 frames, then fails as `answer` says."""
    key = "late"
    def reset(self, seed=None):
        self.t = 0
    def act(self, obs):
        self.t += 1
        return self.answer() if self.t > 100 else 5

class Raises(Late):
    key = "raises"
    def answer(self):
        raise RuntimeError("boom")

class OutOfRange(Late):
    key = "out_of_range"
    def answer(self):
        return 99

class NotANumber(Late):
    key = "nan"
    def answer(self):
        return "left"

class BadKey(Constant):
    key = "bad key!"

class AlwaysWrong(Constant):
    key = "always_wrong"
    def act(self, obs):
        return 42
'''

BEFORE_ANY_WORKER = [  # (partner, what the line says): exit 2
    ("noisy(B44)", "--partner B44: no policy of the bait seat"),
    ("noisy(no_such_module:Alice)", "cannot be imported (ModuleNotFoundError"),
    ("lab_broken:Alice", "cannot be imported (RuntimeError: broken on import)"),
    ("lab:BadKey", "its key 'bad key!' is not 1-64 of letters"),
    ("lab:AlwaysWrong", "returned 42, not an action"),
    ("switch(B1)", "switch(...) needs two partners"),
]
IN_A_WORKER = [  # exit 1
    ("lab:Raises", "RuntimeError: boom"),
    ("lab:OutOfRange", "returned 99, not an action"),
    ("noisy(lab:NotANumber)", "returned 'left', not an action"),
]


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> str:  # noqa: ANN001 - pytest's factory
    folder = tmp_path_factory.mktemp("lab")
    (folder / "lab.py").write_text(LAB)
    (folder / "lab_broken.py").write_text('raise RuntimeError("broken on import")\n')
    return str(folder)


def tsf_eval(partner: str, lab: str, out: str) -> tuple[subprocess.CompletedProcess, float]:
    command = [sys.executable, "-m", "services.commands", "eval", "-q", "--partner", partner, "--seeds", "2"]
    command += ["--workers", "1", "--no-identify", "--strategy", "cem", "--window", "150", "--out", out]
    command += ["--sweep", f"f{uuid.uuid4().hex[:8]}"]
    env = os.environ | {"PYTHONPATH": lab}
    started = time.monotonic()
    done = subprocess.run(
        command, capture_output=True, text=True, timeout=120, env=env, stdin=subprocess.DEVNULL
    )
    return done, time.monotonic() - started


def last_line(done: subprocess.CompletedProcess) -> str:
    return done.stderr.strip().splitlines()[-1]


@pytest.mark.parametrize(("partner", "says"), BEFORE_ANY_WORKER)
def test_a_mistake_the_coordinator_sees_is_one_line_and_exit_2_before_workers(partner, says, lab, tmp_path):
    done, seconds = tsf_eval(partner, lab, str(tmp_path / "out"))
    assert done.returncode == 2, done.stderr[-2000:]
    assert last_line(done).startswith("tsf eval: --partner") and says in last_line(done)
    assert "Traceback" not in done.stderr and "worker" not in done.stderr
    assert seconds < 30


@pytest.mark.parametrize(("partner", "says"), IN_A_WORKER)
def test_a_job_failing_in_a_worker_ends_the_run_naming_job_partner_and_seed(partner, says, lab, tmp_path):
    done, seconds = tsf_eval(partner, lab, str(tmp_path / "out"))
    assert done.returncode == 1, done.stderr[-2000:]
    line = last_line(done)
    assert line.startswith("tsf eval: job team-0.") and f"partner {partner}, seed 0:" in line
    assert "at frame 100" in line and says in line and "keeps the jobs done" in line
    assert "Traceback" not in done.stderr
    assert seconds < 60


def test_a_job_no_live_worker_takes_fails_the_run_at_once(bus, spawn, tmp_path):
    """The only worker cannot import the plug-in the coordinator can: the run fails, naming why."""
    sweep = f"n{uuid.uuid4().hex[:8]}"
    spawn("worker", bus.config(), "--sweep", sweep, "--id", "without")
    job = spec("team-0", "team", {"role": "shooter", "games": [["x", "S4", 0]]}, 1, ("no_lab_here:Alice",))
    started = time.monotonic()
    with (
        Coordination(bus.config(listen=True), sweep, tmp_path / "j.journal") as coordination,
        pytest.raises(Failure, match=r"no live worker will take job team-0\.\w+: worker without said: "),
    ):
        on_workers(coordination)([job])
    assert time.monotonic() - started < 60


def test_the_core_ends_a_run_on_a_job_failure_and_on_no_worker_left():
    jobs = [spec(f"j{i}", "table", {"i": i}, 1) for i in range(3)]
    state = Coordinator(jobs, {})
    for worker in ("a", "b"):
        state.worker_up(worker)
    sent = state.assignments(0.0, 10.0)
    state.refused("a", sent[0][1].id, "no plug-in")
    assert state.failure == "" and state.waiting  # b is still live: a's job waits for it
    state.job_failed("b", sent[1][1].id, "partner x, seed 1: boom")
    assert state.failure.startswith(f"job {sent[1][1].id} failed on worker b: partner x, seed 1: boom")
    alone = Coordinator(jobs, {})
    alone.worker_up("a")
    alone.refused("a", alone.assignments(0.0, 10.0)[0][1].id, "no plug-in")
    assert alone.failure.startswith("no live worker will take job j0.")
