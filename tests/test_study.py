"""The whole study end to end with headless stand-in participants over the page's WebSocket
protocol: consent, balanced roles, sessions with hidden agents, a drop-out who resumes, a restarted
server, trials past their time, many participants at once, and every trial recorded with its sidecar."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
from conftest import STAND_IN_TOKEN
from test_match_processes import in_session

from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.serving import Serving
from services.study.standin import stand_in
from services.study.trial import PROBLEM
from services.study.visit import RETRIES
from shared.game import HUMAN, other

TEST = STAND_IN_TOKEN
VARIANTS = (Variant.read("strong", "B5", "S5"), Variant.read("adaptive", adapter="adaptive-T30-cem"))


@pytest.mark.long
@pytest.mark.slow
def test_stand_ins_run_the_study_with_a_drop_out_who_resumes(tmp_path, wait_until, study_server):
    config = StudyConfig(
        "e2e", VARIANTS, trials=1, trial_seconds=1.5, seed=3, consent="Agree?", end="Bye now."
    )
    stop, url, server = study_server(config, tmp_path)
    leaver = asyncio.run(stand_in(url, leave_after=10, test=TEST))
    assert not leaver.done and leaver.agents == ["Agent 1"] and leaver.participant == "P001"
    refused = asyncio.run(stand_in(url, resume=(leaver.participant, "not-the-key"), test=TEST))
    assert refused.refused.startswith("unknown participant or resume key. If this is wrong, please contact")
    back = asyncio.run(stand_in(url, resume=(leaver.participant, leaver.key), test=TEST))
    second = asyncio.run(stand_in(url, test=TEST))
    dropped = tmp_path / "recordings" / "e2e-P001-s1t1.study.json"
    assert wait_until(dropped.exists, timeout=20), "the cut trial is ended and written down"
    stop.set()
    study = server.result(timeout=60)

    assert back.done and back.role == leaver.role and back.agents == ["Agent 1", "Agent 2"]
    assert second.done and second.participant == "P002" and second.role == other(leaver.role)
    assert (leaver.consent, second.consent, back.consent) == ("Agree?", "Agree?", "")  # asked once
    assert back.end == second.end == "Bye now."
    assert len(back.kills) == len(second.kills) == 2
    assert (back.set_ups, second.set_ups) == (2, 2), "each game's set-up is said, with its length"

    attempts = {p.id: [(a["session"], a["trial"], a["attempt"], a["status"]) for a in p.attempts]
                for p in study.participants.values()}  # fmt: skip
    assert attempts == {
        "P001": [(1, 1, 1, "failed"), (1, 1, 2, "done"), (2, 1, 1, "done")],  # the cut one: a fragment
        "P002": [(1, 1, 1, "done"), (2, 1, 1, "done")],
    }
    for participant in study.participants.values():
        met = []
        for attempt in participant.attempts:
            sidecar = json.loads((tmp_path / "recordings" / f"{attempt['match']}.study.json").read_text())
            assert sidecar["participant"] == participant.id and sidecar["role"] == participant.role
            assert (sidecar["session"], sidecar["trial"], sidecar["status"]) == (
                attempt["session"], attempt["trial"], attempt["status"]
            )  # fmt: skip
            assert sidecar["agent"] == f"Agent {attempt['session']}"
            variant = next(v for v in VARIANTS if v.name == sidecar["variant"])
            met.append(variant.name)
            recording = load(tmp_path / "recordings" / f"{attempt['match']}.tsflog")
            agent_role = other(participant.role)
            adaptive = variant.adaptive(agent_role, 0)
            agent = adaptive.name if adaptive else str(getattr(variant, agent_role))
            assert recording.start.policies == {participant.role: HUMAN, agent_role: agent}
            assert bool(recording.adapter) == bool(variant.adapter)  # the adapter watched the person
            assert recording.summary.kills == sidecar["kills"]
            human = [a for _, a in recording.actions if a.role == participant.role]
            assert human and all(a.sender == f"human/{participant.role}" for a in human)
            if attempt["status"] == "done":
                assert any(s.applied[config.roles.index(participant.role)] for s in recording.states)
        assert sorted(set(met)) == sorted(v.name for v in VARIANTS)  # each variant met


@pytest.mark.slow  # over 15 s of real processes; runs with -m slow
def test_a_trial_past_its_time_is_ended_and_offered_again_then_a_problem_is_shown(tmp_path, study_server):
    config = StudyConfig("late", (VARIANTS[0],), trials=1, trial_seconds=2.0)
    # 10 ms beyond its length from Ready: no match ends that soon (its summary comes after its last frame)
    stop, url, server = study_server(config, tmp_path, Serving(trial_timeout=0.01, test_token=TEST))
    report = asyncio.run(stand_in(url, test=TEST))
    assert report.refused == PROBLEM and report.again == RETRIES - 1 and not report.done, report
    stop.set()
    attempts = server.result(timeout=60).participants["P001"].attempts
    assert [(a["attempt"], a["status"]) for a in attempts] == [(n, "failed") for n in range(1, RETRIES + 1)]
    for attempt in attempts:
        sidecar = json.loads((tmp_path / "recordings" / f"{attempt['match']}.study.json").read_text())
        assert sidecar["status"] == "failed"


@pytest.mark.slow  # over 15 s of real processes; runs with -m slow
def test_a_restarted_server_resumes_everyone(tmp_path, study_server):
    config = StudyConfig("again", (VARIANTS[0],), trials=2, trial_seconds=1.0)
    stop, url, server = study_server(config, tmp_path)
    leaver = asyncio.run(stand_in(url, leave_after=10, test=TEST))
    stop.set()
    server.result(timeout=60)
    _, url, server = study_server(config, tmp_path)  # the same study directory
    back = asyncio.run(stand_in(url, resume=(leaver.participant, leaver.key), test=TEST))
    assert back.done and back.role == leaver.role and len(back.kills) == 2
    fresh = asyncio.run(stand_in(url, test=TEST))
    assert fresh.participant == "P002" and fresh.role == other(leaver.role)


@pytest.mark.slow
def test_eight_stand_ins_at_once_each_in_a_match_of_their_own(tmp_path, study_server):
    """Eight participants arrive together (each from an address of its own, as people do: one
    address gets at most ADDRESS_BURST ids at once) with room for six matches at once: two wait in
    the queue and are told their place; every trial is played, recorded completely and marked done."""
    config = StudyConfig("many", (VARIANTS[0],), trials=1, trial_seconds=3.0, seed=5)
    stop, url, server = study_server(config, tmp_path, Serving(max_matches=6, test_token=TEST))
    try:

        async def crowd():  # noqa: ANN202
            return await asyncio.gather(
                *(stand_in(url, seed=i, test=TEST, address=f"127.0.0.{i + 2}") for i in range(8))
            )

        reports = asyncio.run(asyncio.wait_for(crowd(), 600))
    finally:
        stop.set()
    study = server.result(timeout=60)
    assert all(r.done for r in reports), [(r.participant, r.refused) for r in reports]
    assert sum(r.queued > 0 for r in reports) >= 2
    assert sorted(r.participant for r in reports) == [f"P{i:03d}" for i in range(1, 9)]
    for participant in study.participants.values():
        assert [a["status"] for a in participant.attempts][-1] == "done"
        done = next(a for a in participant.attempts if a["status"] == "done")
        recording = load(tmp_path / "recordings" / f"{done['match']}.tsflog")
        assert recording.problems() == [] and len(recording.states) == config.frames + 1


def study_file(tmp_path: Path, name: str, trials: int = 1, seconds: float = 600) -> Path:
    """A study config: `trials` trials of `seconds` with one static agent."""
    config = tmp_path / f"{name}.toml"
    variant = '[[variants]]\nname = "s"\nbait = "B5"\nshooter = "S5"\n'
    config.write_text(f'name = "{name}"\ntrials = {trials}\ntrial_seconds = {seconds}\n{variant}')
    return config


@contextlib.contextmanager
def study_command(
    tmp_path: Path, name: str = "long", trials: int = 1, seconds: float = 600
) -> Iterator[tuple[subprocess.Popen, str]]:
    """A real `tsf study` process (study `name`: `trials` trials of `seconds` with one static agent,
    its journal and recordings in tmp_path/name) on a free port: (the process, its address); its
    process group is killed at the end. Started again, it resumes the study."""
    config = study_file(tmp_path, name, trials, seconds)
    server = subprocess.Popen(
        [sys.executable, "-m", "services.commands", "study", str(config), "--out", str(tmp_path),
         "--port", "0", "--test-token", TEST],
        stdout=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        line = ""
        while "http" not in line:
            line = server.stdout.readline()
            assert line, "the server printed no address"
        yield server, line[line.index("http") :].split()[0]
    finally:  # its process group, even once the server is gone: nothing is left if a test fails
        with contextlib.suppress(ProcessLookupError):
            os.killpg(server.pid, signal.SIGKILL)
        server.wait()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=lambda s: s.name)
def test_a_study_server_stopped_or_killed_mid_trial_leaves_no_process_behind(tmp_path, wait_until, sig):
    """SIGTERM ends the study and every process it started; SIGKILL leaves the server no time to,
    and they end by themselves: the pool's services (PR_SET_PDEATHSIG), the judge's worker (it
    watches its pipe from the server) and with it multiprocessing's resource tracker. Before, the
    last two ran on for hours after a SIGKILL, re-parented to init."""
    with study_command(tmp_path) as (server, url):
        asyncio.run(stand_in(url, leave_after=30, test=TEST))  # the match runs out for ten minutes
        started = in_session(server.pid)  # the server, its pool's sim, agent and recorder, the judge's
        pool = [p for p in started.values() if "--pool study-" in p]  # worker, the resource tracker
        assert len(pool) == 3 and any("multiprocessing.spawn" in p for p in started.values()), started
        assert any("resource_tracker" in p for p in started.values()), started
        server.send_signal(sig)
        assert server.wait(60) == (0 if sig == signal.SIGTERM else -signal.SIGKILL)
        assert wait_until(lambda: not in_session(server.pid), timeout=5), in_session(server.pid)


def test_a_study_server_that_fails_at_its_start_leaves_no_process_behind(tmp_path, wait_until):
    """Its port taken: the server fails after its pool and judge have started, and ends them."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        server = subprocess.Popen(
            [sys.executable, "-m", "services.commands", "study", str(study_file(tmp_path, "start")),
             "--out", str(tmp_path),
             "--port", str(taken.getsockname()[1])],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
        )  # fmt: skip
        try:
            _, err = server.communicate(timeout=120)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(server.pid, signal.SIGKILL)
    assert server.returncode != 0 and "Traceback" not in err, err
    assert wait_until(lambda: not in_session(server.pid), timeout=5), in_session(server.pid)


def test_a_second_server_on_the_same_study_is_refused_naming_the_first(tmp_path):
    """Both ran, handed out the same participant ids and overwrote each other's records."""
    with study_command(tmp_path, "twice") as (server, _):
        second = subprocess.run(
            [sys.executable, "-m", "services.commands", "study", str(tmp_path / "twice.toml"),
             "--out", str(tmp_path), "--port", "0"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert second.returncode == 2, second.stderr
        assert second.stderr.strip().splitlines()[-1] == (
            f"tsf study: --out {tmp_path / 'twice'}: another study server (pid {server.pid}) serves this "
            "study; stop it first"
        )
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0
    with study_command(tmp_path, "twice") as (server, _):  # once it has ended, the next one serves
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0


def test_ctrl_c_during_a_matchs_warm_up_ends_the_server_at_once(tmp_path, wait_until):
    """SIGINT just as a trial's match starts up (its sim not yet listening, the server's session to
    it not yet open): the server exits within seconds (it took a minute, and at times for ever)."""
    import time

    import websockets

    with study_command(tmp_path) as (server, url):

        async def consent() -> None:
            async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
                await ws.send(json.dumps({"type": "hello"}))
                assert json.loads(await ws.recv())["type"] == "consent"
                await ws.send(json.dumps({"type": "consent"}))
                assert json.loads(await ws.recv())["type"] == "participant"
                sent = time.monotonic()  # the trial's match starts now
                server.send_signal(signal.SIGINT)
                status = await asyncio.to_thread(server.wait, 30)
                waited = time.monotonic() - sent
                assert status == 0
                assert waited < 10.0

        asyncio.run(consent())
        assert wait_until(lambda: not in_session(server.pid), timeout=5), in_session(server.pid)


def test_attempts_an_earlier_server_left_are_settled_by_their_recordings(tmp_path):
    """A server killed just after a trial ended (its attempt `running`, the recording complete), a
    page closed mid-trial (`dropped`, a fragment), a server killed during set-up (no recording):
    the next server makes the first `done`, never played again, the others `failed`, offered
    again; each gets its sidecar."""
    from services.recorder.recording_test import Script, record_match
    from services.study.core import Study
    from services.study.trial import reconcile

    study = Study(StudyConfig("settle", VARIANTS, trials=2), tmp_path)
    people = [study.arrive() for _ in range(3)]
    trials = [study.next_trial(p) for p in people]
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    complete, cut = (recordings / f"{t.match}.tsflog" for t in trials[:2])
    record_match(complete, script=Script(match=trials[0].match, frames=60, human=trials[0].role))
    record_match(cut, script=Script(match=trials[1].match, frames=60, human=trials[1].role), summary=False)
    for trial, status in zip(trials, ("running", "dropped", "running"), strict=True):
        study.record(trial, status)
    study.close()

    again = Study(StudyConfig("settle", VARIANTS, trials=2), tmp_path)
    sidecars = reconcile(again)
    assert [(s["participant"], s["status"]) for s in sidecars] == [
        ("P001", "done"),
        ("P002", "failed"),
        ("P003", "failed"),
    ]
    assert all((recordings / f"{t.match}.study.json").exists() for t in trials)
    first, second, third = (again.next_trial(again.participants[p.id]) for p in people)
    assert (first.trial, first.attempt) == (2, 1)  # the complete trial is not played again
    assert (second.trial, second.attempt) == (third.trial, third.attempt) == (1, 2)
    assert reconcile(again) == []  # nothing left to settle
    again.close()


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_a_client_that_consents_and_goes_silent_frees_its_slot_for_a_newcomer(tmp_path, study_server):
    """The only slot is taken by a socket that consents, is offered its trial and never says
    Ready: after the Ready timeout its match ends and its slot goes to the newcomer waiting."""
    import time

    import websockets

    config = StudyConfig("silent", VARIANTS[:1], trials=1, trial_seconds=1.5, seed=3, consent="Agree?")
    serving = Serving(max_matches=1, test_token=TEST, ready_timeout=4.0)
    stop, url, server = study_server(config, tmp_path, serving=serving)

    async def silent() -> list[str]:
        seen = []
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            await ws.send(json.dumps({"type": "hello"}))
            async for text in ws:
                seen.append(json.loads(text).get("type"))
                if seen[-1] == "consent":
                    await ws.send(json.dumps({"type": "consent"}))
                if seen[-1] == "trial":  # offered, the slot held: and now nothing
                    break
            with contextlib.suppress(websockets.ConnectionClosed):
                await asyncio.wait_for(ws.wait_closed(), 30)
        return seen

    async def both() -> tuple[list[str], object, float]:
        hold = asyncio.ensure_future(silent())
        await asyncio.sleep(1.0)
        started = time.monotonic()
        newcomer = await stand_in(url, test=TEST)
        return await hold, newcomer, time.monotonic() - started

    seen, newcomer, waited = asyncio.run(both())
    assert seen[-1] == "trial" and newcomer.done
    assert waited < serving.ready_timeout + 30  # the timeout, then its own start-up and trial
    stop.set()
    study = server.result(timeout=60)
    statuses = {p.id: [a["status"] for a in p.attempts] for p in study.participants.values()}
    assert statuses == {"P001": ["failed"], "P002": ["done"]}


BROKEN = {  # the agent's bait seat of a variant whose match cannot be set up
    "unknown-key": "B99",
    "swapped-seats": "S5",
    "missing-zip": "{tmp}/gone.zip",
}


@pytest.mark.slow
@pytest.mark.long  # 12 s or more in the full run: kept out of the default run
@pytest.mark.parametrize("bait", BROKEN.values(), ids=BROKEN.keys())
def test_a_trial_that_cannot_be_set_up_is_told_at_once_and_takes_no_slot(tmp_path, study_server, bait):
    """A variant whose agent cannot play its seat: its participant is told of a problem at once (no
    attempt again: each would fail the same way), the attempt is written down as failed with the
    reason, and the only slot stays free: the next participant, who meets the good variant first,
    plays (the slot was held for ever, and the participant got a traceback's close 1011)."""
    variants = (Variant.read("broken", bait.format(tmp=tmp_path), "S5"), VARIANTS[0])

    def config(seed: int) -> StudyConfig:
        return StudyConfig("broken", variants, trials=1, trial_seconds=1.5, seed=seed, roles=("shooter",))

    from services.study.core import variant_order

    seed = next(s for s in range(100) if [variant_order(config(s), i)[0] for i in (0, 1)] == [0, 1])
    stop, url, server = study_server(config(seed), tmp_path, Serving(max_matches=1, test_token=TEST))
    first = asyncio.run(asyncio.wait_for(stand_in(url, test=TEST), 60))
    assert first.refused == PROBLEM and first.agents == [], first
    second = asyncio.run(asyncio.wait_for(stand_in(url, test=TEST, leave_after=10), 60))
    assert second.agents and second.states == 10, "the slot was free"
    stop.set()
    study = server.result(timeout=60)
    [failed] = study.participants["P001"].attempts
    assert failed["status"] == "failed"
    sidecar = json.loads((tmp_path / "recordings" / f"{failed['match']}.study.json").read_text())
    assert sidecar["status"] == "failed" and sidecar["variant"] == "broken"


@pytest.mark.slow
@pytest.mark.long  # 12 s or more in the full run: kept out of the default run
def test_a_reload_during_set_up_is_a_resume(tmp_path, study_server):
    """The page is reloaded while its trial is set up (offered, not Ready): the new page resumes
    and plays every trial; the old socket is closed; the cut attempt is set down as failed."""
    import websockets

    config = StudyConfig("reload", VARIANTS[:1], trials=1, trial_seconds=1.5, seed=3, consent="Agree?")
    stop, url, server = study_server(config, tmp_path)

    async def reload() -> tuple[object, object]:
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            async for message in _consenting(ws):
                if message["type"] == "participant":
                    me = (message["participant"], message["key"])
                elif message["type"] == "trial":  # set up, not Ready: and now the page reloads
                    break
            back = await asyncio.wait_for(stand_in(url, resume=me, test=TEST), 60)
            with contextlib.suppress(websockets.ConnectionClosed):
                await asyncio.wait_for(ws.recv(), 5)
            return back, ws.close_reason

    back, reason = asyncio.run(reload())
    assert back.done and len(back.kills) == 1
    assert reason == "the study was opened again in another window"
    stop.set()
    study = server.result(timeout=60)
    assert [a["status"] for a in study.participants["P001"].attempts] == ["failed", "done"]


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_a_consent_flood_from_one_address_leaves_newcomers_from_others_served(tmp_path, study_server):
    """One client loops hello, consent, close (as fast as the server answers, 40 times): it gets at
    most its address's burst of ids and plays no match; four newcomers from other addresses
    meanwhile are all served to the end. (A close that reaches the server just after a slot came
    leaves a failed attempt of a match never played: the close and the slot race.)"""
    import time

    import websockets

    config = StudyConfig("flood", VARIANTS[:1], trials=1, trial_seconds=1.5, seed=3, consent="Agree?")
    stop, url, server = study_server(config, tmp_path, serving=Serving(max_matches=2, test_token=TEST))

    async def flood() -> int:
        for _ in range(40):
            with contextlib.suppress(websockets.ConnectionClosed, OSError):
                async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
                    await ws.send(json.dumps({"type": "hello"}))
                    await ws.recv()  # the consent text
                    await ws.send(json.dumps({"type": "consent"}))
        return 40

    async def everyone() -> tuple[list, float]:
        started = time.monotonic()
        flooding = asyncio.ensure_future(flood())
        newcomers = [stand_in(url, test=TEST, address=f"127.0.0.{n}", seed=n) for n in range(2, 6)]
        served = await asyncio.gather(*newcomers)
        await flooding
        return served, time.monotonic() - started

    served, seconds = asyncio.run(everyone())
    assert all(s.done and s.refused == "" for s in served), [s.refused for s in served]
    assert seconds < 90
    stop.set()
    study = server.result(timeout=60)
    flooder = [p for p in study.participants.values() if p.id not in {s.participant for s in served}]
    assert len(flooder) <= 5  # ADDRESS_BURST ids
    attempts = [a for p in flooder for a in p.attempts]
    assert all(a["status"] == "failed" and a["kills"] is None for a in attempts), attempts
    assert len(list((tmp_path / "recordings").glob("*.tsflog"))) == 4


def test_a_signed_study_takes_only_a_link_signed_for_its_worker_id(tmp_path, study_server):
    """With a link secret, a hello without a worker id, with no signature or with another id's is
    refused with the page's line; the link signed for its worker id gets the consent text."""
    import websockets

    from services.study.admission import UNSIGNED
    from shared.secret import signature

    secret = b"the-study-secret-0123"
    config = StudyConfig("signed", VARIANTS[:1], trials=1, trial_seconds=1.5, consent="Agree?")
    stop, url, server = study_server(config, tmp_path, serving=Serving(test_token=TEST, link_secret=secret))

    async def hello(**fields: str) -> dict:
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            await ws.send(json.dumps({"type": "hello", **fields}))
            return json.loads(await ws.recv())

    signed = signature(secret, "W-17")
    answers = [
        asyncio.run(hello(**fields))
        for fields in (
            {},
            {"worker": "W-17"},
            {"worker": "W-18", "sig": signed},
            {"worker": "W-17", "sig": signed.upper()},
            {"worker": "W-17", "sig": "é" * 64},
            {"worker": " W-17 ", "sig": signed},
        )
    ]
    assert answers[:-1] == [{"type": "refused", "reason": UNSIGNED}] * 5
    assert answers[-1] == {"type": "consent", "text": "Agree?"}
    stop.set()
    assert server.result(timeout=60).participants == {}


async def _consenting(ws) -> AsyncIterator[dict]:  # noqa: ANN001 - a websockets client connection
    """A new participant's socket: hello, consent when asked; every other message the server sends."""
    await ws.send(json.dumps({"type": "hello"}))
    async for text in ws:
        message = json.loads(text)
        if message["type"] == "consent":
            await ws.send(json.dumps({"type": "consent"}))
        else:
            yield message


def _killed_at(moment: str, url: str, server: subprocess.Popen, recordings: Path) -> tuple[str, str]:
    """Play the study as a participant until `moment` of the first trial, then SIGKILL the server:
    `set_up` (the trial offered, its match started, before Ready), `after_end` (the game's end
    shown, before the server has written the trial down), `read_back` (the recording complete on
    disk, and the server about to read it back). Returns (participant, resume key)."""
    import websockets

    def kill() -> None:
        if server.poll() is None:
            os.kill(server.pid, signal.SIGKILL)  # its matches' processes die with it
            server.wait()

    def kill_at_read_back(path: Path) -> None:
        """Once the pool's recorder has written the recording's summary, the server reads it back."""
        while not (path.exists() and load(path).summary is not None):
            time.sleep(0.001)
        kill()

    async def play() -> tuple[str, str]:
        me = ("", "")
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            async for message in _consenting(ws):
                if message["type"] == "participant":
                    me = (message["participant"], message["key"])
                elif message["type"] == "trial":
                    if moment == "set_up":
                        break
                    await ws.send(json.dumps({"type": "ready"}))
                elif message["type"] == "end":
                    if moment == "read_back":
                        await asyncio.to_thread(kill_at_read_back, recordings / f"kill-{me[0]}-s1t1.tsflog")
                    break
            kill()
        return me

    return asyncio.run(play())


@pytest.mark.parametrize(
    "moment",
    [
        "after_end",
        pytest.param("set_up", marks=pytest.mark.slow),
        pytest.param("read_back", marks=pytest.mark.slow),
    ],
)
def test_a_server_killed_at_the_worst_moment_settles_every_attempt_and_plays_no_trial_twice(tmp_path, moment):
    """A real `tsf study` SIGKILLed during the first trial's set-up, just after its end, or while
    it reads the recording back; started again, it settles the attempt it left `running` by its
    recording (`done` if complete, else `failed` and offered again), the participant resumes and
    finishes, every attempt has its sidecar, and no trial is played again once done."""
    from services.study.core import Journal, Study

    directory = tmp_path / "kill"
    with study_command(tmp_path, "kill", trials=2, seconds=2) as (server, url):
        me = _killed_at(moment, url, server, directory / "recordings")
    at_kill = {
        r["attempt"]["match"]: r["attempt"]["status"]
        for r in Journal.read(directory / "study.jsonl")[1:]
        if "attempt" in r
    }
    assert at_kill == {f"kill-{me[0]}-s1t1": "running"}, "killed before the trial was written down"
    with study_command(tmp_path, "kill", trials=2, seconds=2) as (server, url):
        back = asyncio.run(asyncio.wait_for(stand_in(url, resume=me, test=TEST), 120))
        server.send_signal(signal.SIGTERM)
        assert server.wait(60) == 0
    assert back.done, back.refused

    study = Study(StudyConfig.load(tmp_path / "kill.toml"), directory)
    attempts = study.participants[me[0]].attempts
    study.close()
    for attempt in attempts:
        sidecar = json.loads((directory / "recordings" / f"{attempt['match']}.study.json").read_text())
        assert sidecar["status"] == attempt["status"] in ("done", "failed")
    for trial in (1, 2):
        played = [a["status"] for a in attempts if a["trial"] == trial]
        assert played.count("done") == 1 and played[-1] == "done", f"trial {trial}: {played}"
    first = [a["status"] for a in attempts if a["trial"] == 1]
    complete = (
        load(directory / "recordings" / f"kill-{me[0]}-s1t1.tsflog").problems() == []
        if moment != "set_up"
        else False
    )
    assert first == (["done"] if complete else ["failed", "done"]), (moment, first)
    if moment == "read_back":
        assert complete, "the recording was whole on disk when the server died"


def test_a_participant_who_declines_is_told_so_and_nothing_is_recorded(tmp_path, study_server):
    """The consent text states the study's numbers and pay; a decline gets a closing line and the
    socket closes: no id, no journal line, no match."""
    import websockets

    from services.study.admission import DECLINED

    config = StudyConfig("decline", VARIANTS[:1], trials=2, trial_seconds=1.5, pay="GBP 1 via Prolific")
    stop, url, server = study_server(config, tmp_path)

    async def decline() -> list[dict]:
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            await ws.send(json.dumps({"type": "hello"}))
            seen = [json.loads(await ws.recv())]
            await ws.send(json.dumps({"type": "decline"}))
            seen += [json.loads(text) async for text in ws]  # until the server closes
            return seen

    consent, *after = asyncio.run(asyncio.wait_for(decline(), 30))
    assert consent == {"type": "consent", "text": config.consent_text()}
    assert (
        "play 2 games of 1.5 seconds each" in consent["text"] and "Pay: GBP 1 via Prolific" in consent["text"]
    )
    assert after == [{"type": "declined", "text": DECLINED}]
    stop.set()
    study = server.result(timeout=60)
    assert study.participants == {} and len((tmp_path / "study.jsonl").read_text().splitlines()) == 1
    assert not (tmp_path / "recordings").exists()


@pytest.mark.slow
@pytest.mark.long  # 12 s or more in the full run: kept out of the default run
def test_a_practice_game_comes_before_the_first_recorded_one_and_is_no_trial(tmp_path, study_server):
    """With `practice_seconds`, a new participant first plays a short game with the scripted
    partner: offered as practice, kept apart in practice/, neither in the journal nor a sidecar;
    a participant who resumes after beginning the recorded trials gets none."""
    config = StudyConfig("practice", VARIANTS[:1], trials=1, trial_seconds=1.5, seed=3, practice_seconds=1.0)
    stop, url, server = study_server(config, tmp_path)
    report = asyncio.run(asyncio.wait_for(stand_in(url, test=TEST), 120))
    again = asyncio.run(
        asyncio.wait_for(stand_in(url, resume=(report.participant, report.key), test=TEST), 60)
    )
    stop.set()
    study = server.result(timeout=60)

    assert report.done and report.agents == ["a practice partner", "Agent 1"] and len(report.kills) == 2
    assert again.done and again.agents == [], "done already: no practice, no trial"
    (practice,) = (tmp_path / "practice").glob("*.tsflog")
    recording = load(practice)
    assert recording.problems() == [] and len(recording.states) == 30 + 1  # 1 s at 30 frames a second
    assert set(recording.start.policies.values()) == {
        HUMAN,
        "circle" if report.role == "shooter" else "mirror",
    }
    assert [a["match"] for a in study.participants["P001"].attempts] == ["practice-P001-s1t1"]
    assert [p.name for p in (tmp_path / "recordings").iterdir() if "practice-P001-practice" in p.name] == []
