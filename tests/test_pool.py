"""A pool (services/runtime/pool.py) as a study server uses it: real service processes on a real
zenoh router, many matches at once, each recorded complete; a killed service fails the matches it
was playing and is started again, and the next match plays."""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from services.population.seat import SeatSpec
from services.recorder.recording import load
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool, Tokens
from services.sim.engine import Counters
from services.study.trial import run_trial
from shared import keys
from shared.errors import Failure, UsageError
from shared.game import ROLES
from shared.messages import Summary


def plan(match: str, directory: Path, frames: int = 90, **seats: str) -> MatchPlan:
    specs = {role: SeatSpec.parse(name) for role, name in {"bait": "B5", "shooter": "S5", **seats}.items()}
    return MatchPlan(
        match, seed=7, frames=frames, directory=directory, wait_services=10.0, timeout=60, **specs
    )


def complete(path: Path, frames: int) -> None:
    recording = load(path)
    assert recording.problems() == [], recording.problems()
    assert recording.summary is not None and recording.summary.frame == frames


@pytest.fixture(scope="module")
def pool(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201 - a Pool
    with Pool("test-pool", tmp_path_factory.mktemp("pool")) as pool:
        yield pool


def test_a_pool_plays_matches_at_once_each_recorded_complete(pool: Pool) -> None:
    folder = pool.directory / "recordings"
    plans = [plan(f"pool-{n}", folder, shooter=shooter) for n, shooter in enumerate(("S5", "S4", "S1"))]
    plans.append(plan("pool-adaptive", folder, shooter="adaptive-T30-cem"))
    with ThreadPoolExecutor(len(plans)) as threads:
        results = list(threads.map(pool.run, plans))
    for recording, one in zip(results, plans, strict=True):
        assert recording.path == folder / f"{one.match}.tsflog" and recording.summary.frame == one.frames
        complete(recording.path, one.frames)
    adaptive = load(folder / "pool-adaptive.tsflog")
    assert adaptive.start.policies["shooter"] == "adaptive-T30-cem" and adaptive.adapter, "the adapter played"
    assert {r.start.policies["shooter"] for r in results[:3]} == {"S5", "S4", "S1"}


def test_a_stopped_match_is_a_failure_and_its_recording_is_kept(pool: Pool) -> None:
    stop = threading.Event()
    threading.Timer(1.0, stop.set).start()
    with pytest.raises(Failure, match="stopped before its end"):
        pool.run(plan("pool-stopped", pool.directory, frames=900), stop)
    recording = load(pool.directory / "pool-stopped.tsflog")
    assert recording.summary is not None and 0 < recording.summary.frame < 900


def test_a_match_outside_the_pools_directory_or_of_a_used_id_is_refused(pool: Pool, tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="records into"):
        pool.run(plan("pool-elsewhere", tmp_path / "x" / "y"))
    pool.run(plan("pool-once", pool.directory, frames=9))
    with pytest.raises(UsageError, match="new id"):
        pool.run(plan("pool-once", pool.directory, frames=9))


SLOW = pytest.mark.slow  # the sim's (the router's) restart runs by default, the others with -m slow


@pytest.mark.parametrize(
    "service", ["sim", pytest.param("agent", marks=SLOW), pytest.param("recorder", marks=SLOW)]
)
def test_a_killed_service_fails_its_matches_and_the_next_match_plays(pool: Pool, service: str) -> None:
    victim = pool.processes.children[service]
    failure: list[BaseException] = []

    def run() -> None:
        try:
            pool.run(plan(f"pool-killed-{service}", pool.directory, frames=900))
        except Failure as error:
            failure.append(error)

    running = threading.Thread(target=run)
    running.start()
    time.sleep(2.0)  # under way
    os.kill(victim.pid, signal.SIGKILL)
    running.join(60)
    assert failure and "left it before its end" in str(failure[0]), failure
    deadline = time.monotonic() + 30
    while pool.processes.children[service] is victim or pool.restarts[service] == 0:
        assert time.monotonic() < deadline, f"the {service} was not started again"
        time.sleep(0.1)
    complete(pool.run(plan(f"pool-after-{service}", pool.directory, frames=60)).path, 60)


def test_a_pooled_trial_whose_recording_is_incomplete_lists_each_problem_once(pool: Pool) -> None:
    """A summary put early on a match's key (as a broken sim would) ends its recording there: the
    match ends without a failure of its own, and the trial's judge (services/study/judge.py) lists
    each problem of the recording once, then the trial's own (no person played the bait)."""
    match, stop = "pool-trial-cut", threading.Event()
    with ThreadPoolExecutor(1) as threads:
        trial = threads.submit(run_trial, plan(match, pool.directory, frames=300), "bait", stop, pool)
        playing = threading.Event()
        with pool.z.declare_subscriber(keys.state(match), lambda _: playing.set()):
            assert playing.wait(30), "the match did not start"  # its recorder has long been subscribed
        counters = {role: Counters().to_dict() for role in ROLES}
        early = Summary(match=match, frame=5, sender="sim", counters=counters)
        pool.z.put(keys.summary(match), early.encode())
        kills, problems, failure, refused = trial.result(timeout=60)
    assert kills == 0 and failure == "" and not refused and len(problems) == len(set(problems)), problems
    assert problems[0] == "stopped at frame 5 of 300" and not any("incomplete" in p for p in problems)
    assert problems[-1] == "no action of the participant's bait seat was recorded", problems


def test_the_one_wait_for_tokens_ends_when_all_are_up_at_its_timeout_or_on_abort(bus, wait_until) -> None:
    """Tokens: the wait of every launcher (a pool's services, a pooled match's, a hosted match's
    over the study's router) and its watch of them: `on_taken` once, a token gone is `lost`."""
    watcher, services = bus.open(listen=True), bus.open()
    needed = [keys.alive("tk", "agent", "bait"), keys.alive("tk", "sim")]
    taken: list[bool] = []
    with Tokens(watcher, keys.services_alive("tk"), needed, on_taken=lambda: taken.append(True)) as tokens:
        began = time.monotonic()
        assert not tokens.wait(0.3) and time.monotonic() - began >= 0.3 and tokens.missing() == needed
        began = time.monotonic()
        assert not tokens.wait(60, abort=lambda: True) and time.monotonic() - began < 5
        sim = services.liveliness().declare_token(needed[1])
        agent = services.liveliness().declare_token(needed[0])
        assert tokens.wait(10) and tokens.taken() and taken == [True] and tokens.lost() == []
        agent.undeclare()
        assert wait_until(lambda: tokens.lost() == [needed[0]]) and tokens.missing() == [needed[0]]
        agent = services.liveliness().declare_token(needed[0])
        assert tokens.wait(10) and taken == [True], "taken is told once"
        for token in (sim, agent):
            token.undeclare()
