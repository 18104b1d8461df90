"""The recorder service alone on a real bus: the test publishes a match, with a hole and garbage."""

from __future__ import annotations

import dataclasses
import logging
import signal
import subprocess
from concurrent.futures import Future

import msgpack
import pytest
import zenoh

from services.recorder.log import LogWriter, read_log
from services.recorder.recording import load
from services.recorder.service import recording_path, run_pool_recorder, run_recorder
from services.runtime.launch import service_command
from services.sim.engine import Game
from services.sim.match import start_message, state_message, summary_message
from shared import keys
from shared.bus import BusConfig, session
from shared.errors import Failure, UsageError
from shared.game import ROLES, GameConfig
from shared.messages import Action, GameEvent, MatchOrder, PolicySwitch
from shared.provenance import read_sidecar

MATCH, SEED = "rec", 3
POLICIES = {"bait": "circle", "shooter": "mirror"}


class FakeMatch:
    """Publishes the messages of a real game (states skipped where asked) and remembers the valid ones."""

    def __init__(self, z, match: str = MATCH) -> None:  # noqa: ANN001 - a session
        self.z, self.match, self.game, self.sent = z, match, Game(GameConfig(frames=20), SEED), []
        self.state_at: dict[int, int] = {}  # frame -> index of its state in `sent`

    def put(self, key: str, data: bytes, valid: bool = True) -> None:
        self.z.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)
        if valid:
            self.sent.append((key, data))

    def start(self) -> None:
        self.put(
            keys.start(self.match), start_message(self.game, self.match, "sim", "lockstep", POLICIES).encode()
        )

    def frames(self, last: int, skip: tuple[int, ...] = ()) -> None:
        """States (with both seats' actions) up to `last`; the states of `skip` are not published."""
        while self.game.frame <= last:
            frame = self.game.frame
            if frame not in skip:
                self.state_at[frame] = len(self.sent)
                self.put(
                    keys.state(self.match),
                    state_message(self.game, self.match, "sim", (frame % 12, 3)).encode(),
                )
            for role, action in (("bait", frame % 12), ("shooter", 3)):
                self.put(
                    keys.action(self.match, role),
                    Action(
                        match=self.match, frame=frame, sender="agent", role=role, action=action, policy="p"
                    ).encode(),
                )
            self.game.step(frame % 12, 3)

    def summary(self) -> None:
        self.put(keys.summary(self.match), summary_message(self.game, self.match, "sim", {}, {}).encode())


@pytest.fixture
def recorder(bus, tap, background, wait_until, tmp_path):
    """(a FakeMatch, start()): the test holds both seats' tokens (as the agents would); start() runs
    run_recorder in a thread and returns its future once the recorder's token is seen."""
    z = bus.open(listen=True)
    recorded = tap(z, MATCH)
    seats = [z.liveliness().declare_token(keys.alive(MATCH, "agent", role)) for role in ROLES]

    def start() -> Future:
        future = background(run_recorder, bus.config(), MATCH, tmp_path)
        assert wait_until(lambda: recorded.is_alive("recorder"))
        return future

    yield FakeMatch(z), start
    for token in seats:
        token.undeclare()


def test_the_recorder_is_ready_only_once_it_sees_both_seats(bus, tap, background, wait_until, tmp_path):
    """Its token starts the match: declared before the seats' actions can reach it, they could be lost."""
    z = bus.open(listen=True)
    recorded = tap(z, MATCH)
    bait = z.liveliness().declare_token(keys.alive(MATCH, "agent", "bait"))
    background(run_recorder, bus.config(), MATCH, tmp_path)
    assert not wait_until(lambda: recorded.is_alive("recorder"), timeout=0.3)
    shooter = z.liveliness().declare_token(keys.alive(MATCH, "agent", "shooter"))
    assert wait_until(lambda: recorded.is_alive("recorder"))
    for token in (bait, shooter):
        token.undeclare()


def test_a_client_of_the_sims_router_is_ready_at_once_and_records_the_first_actions(
    endpoint, tap, background, wait_until, tmp_path
):
    """run_match's topology: the sim is the router, everything else its client. The recorder's token
    comes before any seat's player (a study offers the trial on it, before the person's Ready), and
    a seat that joins later still reaches it with its first action: every action passes the router."""
    with session(BusConfig("router", (endpoint,))) as router:
        recorded = tap(router, MATCH)
        client = BusConfig("client", (), (endpoint,))
        future = background(run_recorder, client, MATCH, tmp_path, wait_seats=30.0)
        assert wait_until(lambda: recorded.is_alive("recorder"), timeout=10.0)  # not the 30 s for the seats
        with session(client) as seat, seat.liveliness().declare_token(keys.alive(MATCH, "human", "bait")):
            first = Action(match=MATCH, frame=0, sender="human/bait", role="bait", action=3)
            seat.put(keys.action(MATCH, "bait"), first.encode())  # at once, as a Ready does
            match = FakeMatch(router)
            match.start()
            match.summary()
            path = future.result(timeout=10)
    assert [a for _, a in load(path).actions] == [first]


def test_everything_valid_exactly_once_a_gap_for_the_hole_and_no_garbage(recorder):
    match, start = recorder
    future = start()
    match.start()
    match.frames(4)
    match.put(keys.state(MATCH), b"\xc1 garbage", valid=False)
    match.put(keys.event(MATCH), msgpack.packb({"v": 1, "type": "event", "kind": "kill"}), valid=False)
    match.put(
        keys.action(MATCH, "bait"),
        Action(match=MATCH, frame=5, sender="x", role="bait", action=99).encode(),
        valid=False,
    )
    match.put(f"tsf/{MATCH}/elsewhere", msgpack.packb([1, 2]), valid=False)
    # Valid messages where they do not belong: a state on an action key, an action on the state key,
    # the bait's action on the shooter's key, another match's state.
    state = state_message(match.game, MATCH, "sim", (0, 0))
    match.put(keys.action(MATCH, "bait"), state.encode(), valid=False)
    match.put(
        keys.state(MATCH),
        Action(match=MATCH, frame=5, sender="x", role="bait", action=1).encode(),
        valid=False,
    )
    match.put(
        keys.action(MATCH, "shooter"),
        Action(match=MATCH, frame=5, sender="x", role="bait", action=1).encode(),
        valid=False,
    )
    match.put(keys.state(MATCH), dataclasses.replace(state, match="other").encode(), valid=False)
    match.put(
        keys.event(MATCH),
        GameEvent(match=MATCH, frame=4, sender="sim", kind="kill", role="shooter", detail="test").encode(),
    )
    match.put(
        keys.policy(MATCH, "bait"),
        PolicySwitch(match=MATCH, frame=4, sender="adapter", role="bait", policy="idle").encode(),
    )
    match.frames(9, skip=(5, 6))
    match.summary()
    path = future.result(timeout=5)  # it stops by itself after the summary

    records, damage = read_log(path)
    assert damage == []
    at = match.state_at[7]  # the gap record comes right before state 7, the first after the hole
    assert [r.gap or (r.key, r.data) for r in records] == [*match.sent[:at], (5, 6), *match.sent[at:]]
    recording = load(path)
    assert [s.frame for s in recording.states] == [0, 1, 2, 3, 4, 7, 8, 9]
    assert (recording.gaps, recording.missing_frames, recording.undecodable) == ([(5, 6)], 2, 0)
    assert recording.start is not None and recording.summary is not None and len(recording.events) == 1
    made = read_sidecar(path)  # what made the recording, beside it
    assert made["config"] == GameConfig.from_dict(recording.start.config).hash() and made["library"]


def test_a_restarted_recorder_cuts_a_torn_tail_and_records_the_gap(recorder, wait_until, tmp_path):
    match, start = recorder
    first = start()
    match.start()
    match.frames(3)
    path = recording_path(tmp_path, MATCH)
    assert wait_until(lambda: path.exists() and len(read_log(path)[0]) == len(match.sent))
    first.stop.set()  # the recorder stops (killed, say) during the match: no summary in its log
    assert first.result(timeout=5) == path
    with path.open("ab") as log:
        log.write(b"\x40\0\0\0\1\2\3\4 torn")  # a record cut short by a crash
    assert read_log(path)[1][-1].torn

    match.frames(5)  # published while no recorder ran
    second = start()
    match.frames(8)
    match.summary()
    assert second.result(timeout=5) == path
    recording = load(path)
    assert recording.clean
    assert [s.frame for s in recording.states] == [0, 1, 2, 3, 6, 7, 8]
    assert recording.gaps == [(4, 5)]


def test_a_second_match_under_the_same_id_is_not_recorded(recorder, tmp_path):
    match, start = recorder
    first = start()
    match.start()
    match.frames(3)
    match.start()  # another sim starts a match under this id
    match.frames(6)
    with pytest.raises(Failure, match=f"a second match started under the id {MATCH}; it was not recorded"):
        first.result(timeout=5)
    recording = load(recording_path(tmp_path, MATCH))
    assert recording.starts == 1 and [s.frame for s in recording.states] == [0, 1, 2, 3]


def test_the_recording_ends_when_the_sim_s_token_goes_away(recorder, tmp_path):
    """A killed sim sends no summary: the recorder closes the log as it is (incomplete) and exits."""
    match, start = recorder
    sim = match.z.liveliness().declare_token(keys.alive(MATCH, "sim"))
    future = start()
    match.start()
    match.frames(3)
    sim.undeclare()
    assert future.result(timeout=5) == recording_path(tmp_path, MATCH)
    assert load(future.result()).problems() == ["no summary (last state: frame 3)"]


def test_the_log_of_a_finished_match_is_never_appended_to(recorder, tmp_path):
    match, start = recorder
    first = start()
    match.start()
    match.frames(2)
    match.summary()
    path = first.result(timeout=5)
    before = path.read_bytes()
    with pytest.raises(UsageError, match=f"--match {MATCH}: .* holds a finished match of this id"):
        run_recorder(BusConfig(), MATCH, tmp_path)
    assert path.read_bytes() == before


POOL = "lab"


def order(match: str, folder: str = "") -> bytes:
    names = {"bait": "circle", "shooter": "mirror"}
    return MatchOrder(match=match, frame=0, sender="pool/lab", names=names, folder=folder).encode()


class Pool:
    """The pool's router (its sim's session: it publishes the matches) with a pool recorder client."""

    def __init__(self, router, client: BusConfig, tap, wait_until) -> None:  # noqa: ANN001 - fixtures
        self.router, self.client, self.wait_until = router, client, wait_until
        self.taps: dict[str, object] = {}
        self.tap = tap
        pool_alive = []
        router.liveliness().declare_subscriber(
            keys.pool_alive(POOL, "recorder"), lambda s: pool_alive.append(s.kind), history=True
        )
        self.pool_alive = pool_alive

    def order(self, match: str, folder: str = "") -> FakeMatch:
        """Order `match` (as the launcher does, more than once) and return it once the recorder's
        token for it is seen."""
        tap = self.watch(match)
        self.router.put(keys.pool_order(POOL), order(match, folder))
        self.router.put(keys.pool_order(POOL), order(match, folder))  # re-put: ignored
        assert self.wait_until(lambda: tap.is_alive("recorder"), timeout=10)
        return FakeMatch(self.router, match)

    def watch(self, match: str):  # noqa: ANN201 - a Tap
        self.taps[match] = self.tap(self.router, match)
        return self.taps[match]

    def ended(self, match: str) -> bool:
        return self.wait_until(lambda: not self.taps[match].is_alive("recorder"), timeout=10)


@pytest.fixture
def pool_router(endpoint, tap, wait_until):
    """A Pool with no recorder yet."""
    with session(BusConfig("router", (endpoint,))) as router:
        yield Pool(router, BusConfig("client", (), (endpoint,)), tap, wait_until)


@pytest.fixture
def pool(pool_router, background, wait_until, tmp_path):
    """(a Pool, the pool recorder's future): the recorder runs as the pool's client, into tmp_path."""
    future = background(run_pool_recorder, pool_router.client, POOL, tmp_path)
    assert wait_until(lambda: pool_router.pool_alive == [zenoh.SampleKind.PUT], timeout=10)
    return pool_router, future


def records(path) -> list:  # noqa: ANN001 - a Path
    return [(r.key, r.data) for r in read_log(path)[0]]


def test_a_pool_records_overlapping_matches_from_their_orders_into_their_folders(pool, tmp_path):
    made, future = pool
    a = made.order("pa", folder="one")
    a.start()
    a.frames(3)
    b = made.order("pb", folder="two")
    b.start()
    a.frames(6)
    b.frames(4)
    a.summary()
    recorded = len(a.sent)
    assert made.ended("pa")
    b.frames(8)
    a.frames(9)  # after its end: nothing of match pa is subscribed any more
    made.router.put(keys.pool_order(POOL), order("pa", "one"))  # an order of a match it had: ignored
    b.summary()
    assert made.ended("pb")
    assert not made.wait_until(lambda: made.taps["pa"].is_alive("recorder"), timeout=0.5)
    a_path, b_path = tmp_path / "one" / "pa.tsflog", tmp_path / "two" / "pb.tsflog"
    assert records(a_path) == a.sent[:recorded] and records(b_path) == b.sent
    assert all(load(path).summary is not None and load(path).clean for path in (a_path, b_path))
    assert sorted(p.name for p in tmp_path.rglob("*.tsflog")) == ["pa.tsflog", "pb.tsflog"]
    assert not future.done()


def test_a_killed_sim_ends_its_match_s_recording_only(pool, tmp_path):
    made, _ = pool
    sims = {m: made.router.liveliness().declare_token(keys.alive(m, "sim")) for m in ("ka", "kb")}
    a, b = made.order("ka"), made.order("kb")
    for match in (a, b):
        match.start()
        match.frames(3)
    sims["ka"].undeclare()  # its sim is gone: the recording ends as it is
    assert made.ended("ka")
    b.frames(6)
    b.summary()
    assert made.ended("kb")
    sims["kb"].undeclare()
    killed = load(tmp_path / "ka.tsflog")
    assert killed.clean and killed.problems() == ["no summary (last state: frame 3)"]
    assert records(tmp_path / "kb.tsflog") == b.sent


def test_an_order_it_cannot_take_is_dropped_with_one_line_and_the_pool_records_on(pool, tmp_path, caplog):
    made, future = pool
    with LogWriter(tmp_path / "done.tsflog") as finished:  # a finished match's log: never appended to
        finished.write(
            keys.summary("done"), summary_message(Game(GameConfig(), 1), "done", "sim", {}, {}).encode()
        )
    caplog.set_level(logging.WARNING)
    bad = msgpack.unpackb(order("up", folder="x"))
    made.router.put(keys.pool_order(POOL), b"\xc1 garbage")
    made.router.put(keys.pool_order(POOL), msgpack.packb({**bad, "folder": "../up"}))
    done = made.watch("done")
    made.router.put(keys.pool_order(POOL), order("done"))
    good = made.order("good")
    good.start()
    good.summary()
    assert made.ended("good") and load(tmp_path / "good.tsflog").summary is not None
    assert not (tmp_path.parent / "up.tsflog").exists() and not future.done()
    assert not done.is_alive("recorder") and len(read_log(tmp_path / "done.tsflog")[0]) == 1
    lines = [r.getMessage() for r in caplog.records]
    assert sum("dropped input on tsf/pool/lab/order" in line for line in lines) == 2  # two reasons
    assert [line for line in lines if "not recorded" in line] == [
        f"match done not recorded: --match done: {tmp_path / 'done.tsflog'} holds a finished match"
        " of this id; give the new one another id"
    ]


def test_sigterm_closes_every_open_log(pool_router, spawn, tmp_path, wait_until):
    made = pool_router
    recorder = spawn("recorder", made.client, "--pool", POOL, "--out", str(tmp_path))
    assert wait_until(lambda: made.pool_alive == [zenoh.SampleKind.PUT], timeout=30)
    matches = [made.order(m) for m in ("ta", "tb")]
    for match in matches:
        match.start()
        match.frames(3)
    assert wait_until(
        lambda: all(len(read_log(tmp_path / f"{m.match}.tsflog")[0]) == len(m.sent) for m in matches)
    )
    recorder.send_signal(signal.SIGTERM)
    assert recorder.wait(10) == 0
    for match in matches:
        recording = load(tmp_path / f"{match.match}.tsflog")
        assert recording.clean and [s.frame for s in recording.states] == [0, 1, 2, 3]
        assert records(recording.path) == match.sent


def test_a_disk_error_fails_that_match_s_recording_alone_with_one_line(
    pool_router, tmp_path, wait_until, capfd
):
    """A disk error mid-match (here a file size limit, which binds root too: EFBIG) ends that
    match's recording with one line, as it stands; the recorder process serves on and records the
    next match complete."""
    made = pool_router
    command = service_command("recorder", made.client, "--pool", POOL, "--out", str(tmp_path))
    recorder = subprocess.Popen(["prlimit", f"--fsize={16 * 1024}", "--", *command], stdin=subprocess.DEVNULL)
    try:
        assert wait_until(lambda: made.pool_alive == [zenoh.SampleKind.PUT], timeout=30)
        full = made.order("full")
        full.start()
        full.frames(19)  # about 40 KB: past the limit near frame 7
        assert made.ended("full")
        fits = made.order("fits")
        fits.start()
        fits.frames(3)  # about 10 KB
        fits.summary()
        assert made.ended("fits") and records(tmp_path / "fits.tsflog") == fits.sent
        assert recorder.poll() is None, "the recorder serves on"
        recorder.send_signal(signal.SIGTERM)
        assert recorder.wait(10) == 0
    finally:
        if recorder.poll() is None:
            recorder.kill()
        recorder.wait()
    failed = [line for line in capfd.readouterr().err.splitlines() if "failed" in line]
    assert len(failed) == 1 and failed[0].endswith(
        f"tsf.recorder ERROR recording {tmp_path / 'full.tsflog'} failed: [Errno 27] File too large"
    ), failed
    cut = load(tmp_path / "full.tsflog")  # as it stood: the records written before the error
    assert cut.summary is None and [s.frame for s in cut.states] == list(range(len(cut.states)))
    assert (
        0 < len(cut.states) < 20
        and records(tmp_path / "full.tsflog") == full.sent[: len(read_log(cut.path)[0])]
    )
