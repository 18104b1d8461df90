"""Studies across machines: the study server is the router, `tsf match-host` processes connect to
it over loopback and run the trials' matches, and every recording comes back into the study's
directory with its hash checked; a host killed mid-trial leaves no recording marked done, and the
trial is played again on another host; a peer on the router without the study's host secret can
neither offer slots nor return a recording."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import hashlib
import hmac
import json
import signal
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgpack
import pytest
import zenoh
from conftest import STAND_IN_TOKEN, wait_until
from test_match_processes import in_session

from services.population.seat import SeatSpec
from services.recorder.recording import load
from services.runtime.launch import MatchPlan
from services.sim.engine import Counters
from services.study.core import StudyConfig, Variant
from services.study.host import Host, offer_of, sha256
from services.study.remote import Remote
from services.study.serving import Serving
from services.study.standin import stand_in
from services.study.trial import run_trial
from shared import keys
from shared.bus import BusConfig, free_endpoint, session
from shared.errors import Failure
from shared.game import HUMAN, ROLES
from shared.messages import (
    HostStatus,
    MatchAnswer,
    MatchDone,
    MatchOffer,
    Message,
    RecordingChunk,
    Summary,
    decode,
    recording_query,
    sealed,
)

TEST = STAND_IN_TOKEN
SECRET = b"the-hosts-secret-0123"  # the study's host secret, shared with its hosts
PERSON_AND_S5 = {"bait": SeatSpec.parse(HUMAN), "shooter": SeatSpec.parse("S5")}


@pytest.fixture
def match_host(tmp_path):  # noqa: ANN201
    """Start `tsf match-host` processes: host(name, endpoint) -> Popen; all are killed at teardown."""
    started: list[subprocess.Popen] = []

    secret = tmp_path / "host-secret"
    secret.write_bytes(SECRET + b"\n")

    def start(name: str, endpoint: str, slots: int = 1) -> subprocess.Popen:
        command = [
            sys.executable, "-m", "services.commands", "match-host", "--connect", endpoint,
            "--slots", str(slots), "--id", name, "--out", str(tmp_path / name), "--host-secret", str(secret),
        ]  # fmt: skip
        started.append(subprocess.Popen(command, start_new_session=True))
        return started[-1]

    yield start
    for host in started:
        with contextlib.suppress(ProcessLookupError):
            host.kill()
        host.wait()


def hosted(endpoint: str) -> Serving:
    """A study server that runs no match itself: every trial goes to a match host."""
    return Serving(max_matches=0, test_token=TEST, hosts=BusConfig("router", (endpoint,)), host_secret=SECRET)


@pytest.mark.slow
@pytest.mark.long  # 12 s or more in the full run: kept out of the default run
def test_trials_run_on_a_match_host_and_their_recordings_come_back_whole(tmp_path, study_server, match_host):
    """A static and an adaptive agent, each in a match on the host; the participant's seat is played
    over the router, and each recording is the host's, byte for byte, complete."""
    endpoint = free_endpoint()
    variants = (Variant.read("strong", "B5", "S5"), Variant.read("adaptive", adapter="adaptive-T30-cem"))
    config = StudyConfig("remote", variants, trials=1, trial_seconds=2.0, seed=4)
    stop, url, server = study_server(config, tmp_path / "study", hosted(endpoint))
    match_host("lab-1", endpoint)
    report = asyncio.run(asyncio.wait_for(stand_in(url, test=TEST), 240))
    stop.set()
    study = server.result(timeout=60)

    assert report.done and len(report.kills) == 2, report.refused
    attempts = study.participants["P001"].attempts
    assert [a["status"] for a in attempts] == ["done", "done"]
    for attempt, kills in zip(attempts, report.kills, strict=True):
        here = tmp_path / "study" / "recordings" / f"{attempt['match']}.tsflog"
        there = tmp_path / "lab-1" / here.name
        assert hashlib.sha256(here.read_bytes()).hexdigest() == hashlib.sha256(there.read_bytes()).hexdigest()
        recording = load(here)
        assert recording.problems() == [] and len(recording.states) == config.frames + 1
        assert recording.summary.kills == attempt["kills"] == kills
        human = [a for _, a in recording.actions if a.role == report.role]
        assert human and all(a.sender == f"human/{report.role}" for a in human), "played over the router"
        sidecar = json.loads(here.with_suffix(".study.json").read_text())
        assert sidecar["status"] == "done" and sidecar["participant"] == "P001"
        assert bool(recording.adapter) == (sidecar["variant"] == "adaptive"), "the host ran the adapter"
    assert not list((tmp_path / "study" / "recordings").glob("*.part"))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=lambda s: s.name)
def test_a_match_host_stopped_or_killed_leaves_no_process_behind(tmp_path, study_server, match_host, sig):
    """Its pool's services end with it, however it ends (found by its session, not by name)."""
    endpoint = free_endpoint()
    config = StudyConfig("gone", (Variant.read("strong", "B5", "S5"),), trials=1, trial_seconds=2.0)
    study_server(config, tmp_path / "study", hosted(endpoint))
    host = match_host("lab-1", endpoint)
    pool = lambda: [c for c in in_session(host.pid).values() if "--pool lab-1-" in c]  # noqa: E731
    assert wait_until(lambda: len(pool()) == 4, timeout=60), in_session(host.pid)  # an adaptive pool
    host.send_signal(sig)
    host.wait(60)
    assert wait_until(lambda: not in_session(host.pid), timeout=10), in_session(host.pid)


@pytest.mark.slow  # over 15 s of real processes; runs with -m slow
def test_a_host_killed_mid_trial_leaves_the_trial_to_be_played_again(tmp_path, study_server, match_host):
    endpoint = free_endpoint()
    config = StudyConfig("killed", (Variant.read("strong", "B5", "S5"),), trials=1, trial_seconds=8.0)
    stop, url, server = study_server(config, tmp_path / "study", hosted(endpoint))
    first = match_host("lab-1", endpoint)
    reports = []
    player = threading.Thread(target=lambda: reports.append(asyncio.run(stand_in(url, test=TEST))))
    player.start()
    try:
        playing = tmp_path / "lab-1" / "killed-P001-s1t1.tsflog"
        assert wait_until(lambda: playing.exists() and playing.stat().st_size > 50_000, timeout=120)
        first.send_signal(signal.SIGKILL)  # its matches' processes die with it (PR_SET_PDEATHSIG)
        first.wait()
        match_host("lab-2", endpoint)
        player.join(240)
    finally:
        stop.set()
    study = server.result(timeout=60)

    assert reports and reports[0].done and reports[0].again == 1, reports
    attempts = study.participants["P001"].attempts
    assert [(a["attempt"], a["status"]) for a in attempts] == [(1, "failed"), (2, "done")]
    recordings = tmp_path / "study" / "recordings"
    assert not (recordings / "killed-P001-s1t1.tsflog").exists(), "no half recording comes back"
    assert not list(recordings.glob("*.part"))
    assert json.loads((recordings / "killed-P001-s1t1.study.json").read_text())["status"] == "failed"
    again = recordings / "killed-P001-s1t1-a2.tsflog"
    assert load(again).problems() == []
    assert again.read_bytes() == (tmp_path / "lab-2" / again.name).read_bytes()


@pytest.mark.long
@pytest.mark.slow
def test_a_recording_whose_hash_differs_never_lands_in_the_study(tmp_path: Path) -> None:
    endpoint = free_endpoint()
    source = tmp_path / "host" / "m.tsflog"
    source.parent.mkdir()
    source.write_bytes(bytes(range(256)) * 1000)  # several chunks
    host = Host("lab-1", 1, source.parent, SECRET)
    host.finished["m"] = source

    def serve(query: zenoh.Query) -> None:
        chunk = host.chunk(str(query.key_expr), query.parameters.get("offset"), query.parameters.get("auth"))
        query.reply(query.key_expr, chunk.encode())

    remote = Remote(BusConfig("router", (endpoint,)), SECRET)
    try:
        with (
            session(BusConfig("client", (), (endpoint,))) as z,
            z.declare_queryable(keys.host_recording("lab-1"), serve),
        ):
            asked = recording_query(keys.host_recording("lab-1", "m"), 0, SECRET)
            assert wait_until(lambda: any(r.ok for r in remote.z.get(asked, timeout=1)), timeout=10)
            done = MatchDone(
                match="m", frame=0, sender="host/lab-1", size=source.stat().st_size, sha256=sha256(source)
            )  # taken as the host's (the seal is checked where it arrives, below)
            remote.fetch("lab-1", "m", done, tmp_path / "study" / "m.tsflog")
            assert (tmp_path / "study" / "m.tsflog").read_bytes() == source.read_bytes()
            with pytest.raises(Failure, match="does not match its sha256"):
                remote.fetch(
                    "lab-1", "m", dataclasses.replace(done, sha256="0" * 64), tmp_path / "study" / "n.tsflog"
                )
            with pytest.raises(Failure, match="did not serve"):
                remote.fetch("lab-1", "x", done, tmp_path / "study" / "x.tsflog")
    finally:
        remote.close()
    assert sorted(p.name for p in (tmp_path / "study").iterdir()) == ["m.tsflog"], (
        "nothing else, nothing half"
    )


def test_a_peer_without_the_host_secret_can_neither_offer_slots_nor_return_a_recording(tmp_path, match_host):
    """A peer on the study's router that holds a host's token, puts its slots (unsealed, or sealed
    with another secret), answers offers, reports the match's end and serves chunks: the server
    sees no slot and takes neither answer nor end nor chunk (each counted and dropped, logged once);
    a real host that holds the secret is seen beside it; and a match host takes no offer, stop or
    recording query that the secret did not seal."""
    endpoint = free_endpoint()
    wrong = b"a-guessed-secret-0123"
    remote = Remote(BusConfig("router", (endpoint,)), SECRET)
    rogue = "lab-9"
    offers: list[MatchOffer] = []

    def answer(query: zenoh.Query) -> None:
        offers.append(decode(query.payload.to_bytes(), MatchOffer))
        yes = MatchAnswer(match=offers[-1].match, frame=0, sender=f"host/{rogue}", accepted=True)
        query.reply(query.key_expr, sealed(yes, wrong).encode())

    def chunk(query: zenoh.Query) -> None:
        data = RecordingChunk(match="m", frame=0, sender=f"host/{rogue}", offset=0, size=3, data=b"abc")
        query.reply(query.key_expr, data.encode())

    try:
        with (
            session(BusConfig("client", (), (endpoint,))) as z,
            z.liveliness().declare_token(keys.host_alive(rogue)),
            z.declare_queryable(keys.host_offer(rogue), answer),
            z.declare_queryable(keys.host_recording(rogue), chunk),
        ):
            status = HostStatus(host=rogue, frame=0, sender=f"host/{rogue}", slots=8, free=8)
            for _ in range(10):
                z.put(keys.host_status(rogue), status.encode())
                z.put(keys.host_status(rogue), sealed(status, wrong).encode())
            match_host("lab-1", endpoint, slots=2)  # a real host, with the secret
            assert wait_until(lambda: remote.hosts() == {"lab-1": 2}, timeout=60)
            assert remote.drops.counts["unauthenticated"] == 20, "every forged status counted"
            # ... which answers no offer and no recording query the secret did not seal
            offer = offer_of(MatchPlan("mx", 0, 60, **PERSON_AND_S5), f"host/{rogue}")
            for payload in (offer.encode(), sealed(offer, wrong).encode()):
                assert not [r for r in z.get(keys.host_offer("lab-1"), payload=payload, timeout=3) if r.ok]
            unsigned = f"{keys.host_recording('lab-1', 'mx')}?offset=0"
            assert not list(z.get(unsigned, timeout=3)), "not even an error"
            plan = MatchPlan(f"m{rogue}", 0, 60, directory=tmp_path, **PERSON_AND_S5)
            with pytest.raises(Failure, match="did not answer"):
                remote.run(rogue, plan, threading.Event())  # its accepted answer is not taken
            assert offers and offers[0].auth, "the server's offer is sealed"
            done = MatchDone(
                match="m", frame=0, sender=f"host/{rogue}", size=3, sha256=hashlib.sha256(b"abc").hexdigest()
            )
            with pytest.raises(Failure, match="did not serve"):
                remote.fetch(rogue, "m", done, tmp_path / "m.tsflog")
            with remote.changed:
                remote.offered.add("m")
            z.put(keys.host_done(rogue), done.encode())
            z.put(keys.host_done(rogue), sealed(done, wrong).encode())
            assert wait_until(lambda: remote.drops.counts["unauthenticated"] >= 24, timeout=10)
            assert remote.done == {} and not (tmp_path / "m.tsflog").exists()
    finally:
        remote.close()


def version_1(message: Message, secret: bytes) -> bytes:
    """`message` as a match host of schema version 1 put it: `v` 1, its id named `match`, sealed with
    the secret over that encoding."""
    record = msgpack.unpackb(message.encode(), raw=False)
    record.update(v=1, match=record.pop(message.ID), auth="")
    record["auth"] = hmac.new(secret, msgpack.packb(record, use_bin_type=True), hashlib.sha256).hexdigest()
    return msgpack.packb(record, use_bin_type=True)


def test_a_match_host_of_schema_version_1_is_refused_as_such() -> None:
    """A version-1 host that holds the secret: the server counts its status as `version` (not as a
    forgery) and sees no slot of it; a host must run the server's version."""
    endpoint = free_endpoint()
    remote = Remote(BusConfig("router", (endpoint,)), SECRET)
    status = version_1(HostStatus(host="lab-1", frame=0, sender="host/lab-1", slots=2, free=2), SECRET)
    try:
        with (
            session(BusConfig("client", (), (endpoint,))) as z,
            z.liveliness().declare_token(keys.host_alive("lab-1")),
        ):
            assert wait_until(
                lambda: z.put(keys.host_status("lab-1"), status) or remote.drops.counts["version"] >= 3
            )
            assert remote.hosts() == {} and remote.drops.counts["unauthenticated"] == 0
    finally:
        remote.close()


def test_a_hosted_trial_whose_recording_is_incomplete_lists_each_problem_once(tmp_path, match_host):
    """A summary put early on the router (as a broken sim would) ends the host's recording there:
    the server is told once every service of the host has taken the match (over the router), and
    the trial's failure lists each problem of the recording it fetched once, from its own verdict
    (the host leaves the judging to it), then the trial's own (no person played the bait)."""
    endpoint = free_endpoint()
    remote = Remote(BusConfig("router", (endpoint,)), SECRET)
    try:
        match_host("lab-1", endpoint)
        assert wait_until(lambda: remote.hosts() == {"lab-1": 1}, timeout=60)
        seats = {"bait": SeatSpec.parse("B5"), "shooter": SeatSpec.parse("S5")}
        plan = MatchPlan("cut", 7, 300, directory=tmp_path, wait_services=10.0, timeout=60, **seats)
        taken = threading.Event()
        with ThreadPoolExecutor(1) as threads:  # no pool here: the trial runs on the host
            trial = threads.submit(
                run_trial, plan, "bait", threading.Event(), None, remote, "lab-1", taken.set
            )
            assert taken.wait(60), "every service of the host took the match"
            playing = threading.Event()
            with remote.z.declare_subscriber(keys.state("cut"), lambda _: playing.set()):
                assert playing.wait(30), "the match did not start"  # its recorder has long been subscribed
            counters = {role: Counters().to_dict() for role in ROLES}
            remote.z.put(
                keys.summary("cut"), Summary(match="cut", frame=5, sender="sim", counters=counters).encode()
            )
            kills, problems, failure, refused = trial.result(timeout=120)
    finally:
        remote.close()
    assert kills == 0 and failure == "" and not refused and len(problems) == len(set(problems)), problems
    assert problems[0] == "stopped at frame 5 of 300" and not any("incomplete" in p for p in problems)
    assert problems[-1] == "no action of the participant's bait seat was recorded", problems
    assert (tmp_path / "cut.tsflog").read_bytes() == (tmp_path / "lab-1" / "cut.tsflog").read_bytes()
