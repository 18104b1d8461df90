"""`tsf study`: the study's server on the human gateway, wired together here. Each participant's
socket stays open across all their trials; each trial is a match of its own, played by the
server's warm pool (services/runtime/pool.py: one sim, agent, recorder and adapter process for all
its matches, kept for the server's life), the participant's seat bridged from this process over
the pool's bus.

Many participants play at once: a match starts with an order to the pool, so it is ready by the
time the participant has read the trial's offer. At most `max_matches` run at once; the other
trials wait in a queue whose place and estimated wait the participant sees. Match hosts on other
machines add capacity (`Serving.hosts`: the study's router): once this machine's `max_matches` are
taken, a trial's match is offered to a live host with a free slot (services/study/remote.py), the
participant's seat is bridged over the router, and the host's recording is fetched into the study
directory with its hash checked before the trial is judged.

Study messages (down): `consent` (text), `declined` (text: the participant said no, nothing was
recorded), `participant` (id and resume key, kept by the browser), `check` (an attention check,
services/study/crowd.py), `wait` (reason, seconds: a game is being set up), `trial` (session,
trial, role, the agent's label; what to read first), `queue` (place, seconds to wait, while the
trial waits for a free match), then the gateway's `state`/`end` frames, and at last `done` (the
end text, code and redirect), `screened` or `problem`. Up: `hello` (optionally with the
participant id and key to resume, the link's parameters and signature), `consent` or `decline`,
`answer`, `ready`, `keys`. The experimenter's dashboard is served beside it
(services/study/dashboard.py).

The parts, each a module named for what it does: `admission.Front` admits each participant
(consent or resume, rate limits, refusals), `visit.Visit` is one participant's session (practice,
attention checks, trials in order, a failed one again), `trial.TrialRunner` runs one trial's match
(slot, start, seat, Ready, judgement), `connection.Socket` is a participant's socket and
`serving.Serving` how the server serves.

Each trial's metadata goes into a sidecar `<match>.study.json` beside its recording, rather than
onto the bus: the participant id is nobody's business but the study's (bus traffic may cross a lab
network), no service needs it, and the contract stays as it is; the match id names study,
participant, session and trial too, so a recording alone still says where it belongs.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import IO

from services.human.gateway import Gateway, Web
from services.runtime.pool import Pool, pool_name
from services.study.admission import Front
from services.study.core import Study, StudyConfig
from services.study.crowd import write_bonuses
from services.study.dashboard import Dashboard, about, overview
from services.study.judge import Judge
from services.study.remote import Remote
from services.study.serving import SERVING, WEB, Serving
from services.study.trial import Matches, TrialRunner, reconcile
from shared.bus import until_stopped
from shared.errors import UsageError
from shared.game import ROLES

log = logging.getLogger("tsf.study")
THREADS = 512  # threads for blocking work off the event loop: two per running match, and more
DRAIN = 60.0  # seconds the stopping server waits for its matches to end and be written down


def one_server(directory: Path) -> IO[str]:
    """The study directory's lock (`server.lock`, holding the server's pid), held until the file is
    closed, or the process ends however it ends. A second server on the same directory is refused
    (UsageError, naming the first one's pid): both ran, handed out the same participant ids and
    overwrote each other's records. An advisory lock (flock): on a shared file system that does not
    carry flock across machines, run one server per directory yourself."""
    directory.mkdir(parents=True, exist_ok=True)
    file = (directory / "server.lock").open("a+")
    _locked(file, directory, fcntl.LOCK_EX)
    file.truncate(0)
    file.write(f"{os.getpid()}\n")
    file.flush()
    return file


def no_server(directory: Path) -> None:
    """Refuse (UsageError) a study directory another server serves, as one_server would, without
    writing anything (`tsf study --check`)."""
    path = directory / "server.lock"
    if path.exists():
        with path.open() as file:
            _locked(file, directory, fcntl.LOCK_SH)


def _locked(file: IO[str], directory: Path, how: int) -> None:
    """Lock `file` (`how`: exclusive or shared) at once, or close it and refuse naming the pid in it."""
    try:
        fcntl.flock(file, how | fcntl.LOCK_NB)
    except BlockingIOError:
        file.seek(0)
        other = file.read().strip() or "unknown"
        file.close()
        raise UsageError(
            "--out", directory, f"another study server (pid {other}) serves this study; stop it first"
        ) from None


def run_study(
    config: StudyConfig,
    directory: str | Path,
    web: Web = WEB,
    stop: threading.Event | None = None,
    on_ready: Callable[[Gateway], None] = lambda gateway: None,
    serving: Serving = SERVING,
) -> Study:
    """Serve the study until `stop` is set, then end every match it started; participants'
    progress lives in `directory` (a restarted server resumes everyone)."""
    stop = stop or threading.Event()
    lock = one_server(Path(directory))  # before anything is read or started
    study = Study(config, directory)
    settled = reconcile(study)
    for sidecar in settled:
        log.info("attempt %s left %s by an earlier server", sidecar["match"], sidecar["status"])
    matches = Matches(serving.max_matches)
    remote = Remote(serving.hosts, serving.host_secret) if serving.hosts else None
    adaptive = any(v.adaptive(role, 0) for v in config.variants for role in ROLES)
    pool = Pool(pool_name("study"), study.directory, adaptive, serving.low_latency)
    judging = None
    try:
        pool.__enter__()
        judging = Judge()
        runner = TrialRunner(study, serving, matches, pool, judging, remote)
        runner.cut = {s["match"] for s in settled if s["status"] == "failed"}  # replayed: the page says why
        front = Front(study, serving, runner, web.trusted)
        gateway = Gateway(None, front.handle, web)
        # A running match holds a thread (run_trial) for its length, its start-up another: asyncio's
        # default pool (cores + 4 threads) would cap the matches at a handful, whatever hosts add.
        gateway.loop.set_default_executor(ThreadPoolExecutor(THREADS, thread_name_prefix="study"))
        if remote is not None:  # a host that comes or goes changes the room in the queue
            remote.on_change = lambda: gateway.loop.call_soon_threadsafe(matches.notify)
        board = serving.dashboard and Dashboard(
            serving.dashboard_token, serving.dashboard, gateway.loop,
            lambda: overview(study, matches.admission, front.playing), matches.endpoints.get,
            serving.low_latency, remote and remote.z, lambda match: about(study, match),
        )  # fmt: skip
        with gateway, board or contextlib.nullcontext():
            on_ready(gateway)
            until_stopped(stop)
            with contextlib.suppress(TimeoutError):  # the pages say so before their matches end
                asyncio.run_coroutine_threadsafe(front.stopping(), gateway.loop).result(5.0)
            matches.stop_all()
            with contextlib.suppress(TimeoutError):  # a match's thread that hangs: leave it to exit
                asyncio.run_coroutine_threadsafe(matches.drained(), gateway.loop).result(DRAIN)
    finally:
        pool.__exit__()
        if judging is not None:
            judging.close()
        if remote is not None:
            remote.close()
        study.close()
        bonuses = write_bonuses(study.config.crowd.bonus, study.participants.values(), study.directory)
        if bonuses is not None:
            log.info("bonuses written to %s", bonuses)
        lock.close()
    return study
