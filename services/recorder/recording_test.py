"""Reading recordings: a real match written in-process as the recorder writes it, loaded, replayed
through the engine and exported to Parquet."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from services.agent.player import Player
from services.recorder.export import TABLES, export, read
from services.recorder.log import GapTracker, LogWriter
from services.recorder.recording import Recording, load, replay
from services.sim.engine import Game
from services.sim.match import event_messages, start_message, state_message, summary_message
from shared import keys
from shared.game import ROLES, GameConfig
from shared.messages import AdapterStatus, PolicySwitch, State

M = "rec-1"
SEED = 5
FRAMES = 60
POLICIES = {"bait": "circle", "shooter": "mirror"}
SWITCH_AT = 30  # the bait switches to idle before answering this frame
ADAPTER = AdapterStatus(
    match=M,
    frame=SWITCH_AT,
    sender="adapter",
    role="shooter",
    strategy="cem",
    window=20,
    filled=20,
    partner="B5",
    policy="S5",
    scores={"B5": -0.5, "B1": -3.0},
)
SWITCH = PolicySwitch(match=M, frame=SWITCH_AT, sender="operator", role="bait", policy="idle", reason="test")


@dataclass(frozen=True)
class Script:
    """What an in-process match plays: its id, seed and length, each seat's policy, what its start
    record announces (default: the policies; "" marks a person's seat), and the adapter statuses and
    policy switches logged just before the seats answer the frame each names."""

    match: str = M
    seed: int = SEED
    frames: int = FRAMES
    policies: dict[str, str] = field(default_factory=lambda: dict(POLICIES))
    announced: dict[str, str] | None = None
    statuses: tuple[AdapterStatus, ...] = (ADAPTER,)
    switches: tuple[PolicySwitch, ...] = (SWITCH,)
    human: str = ""  # a seat whose actions are sent as a person's (human/<role>)


def record_match(
    path: Path,
    tamper: int | None = None,
    lose: int | None = None,
    summary: bool = True,
    script: Script = Script(),  # noqa: B008 - frozen
) -> list[State]:
    """Play a lockstep match (the scripted pair by default) and log every message as the recorder
    does. `tamper`: that frame's state is logged with a wrong hash; `lose`: that state never arrives."""
    m = script.match
    game = Game(GameConfig(frames=script.frames), script.seed)
    players = {role: Player(role, script.policies[role], script.seed) for role in ROLES}
    gaps, published, applied = GapTracker(), [], (0, 0)
    with LogWriter(path) as log:
        announced = script.announced or script.policies
        log.write(keys.start(m), start_message(game, m, "sim", "lockstep", announced).encode())
        while True:
            state = state_message(game, m, "sim", applied)
            published.append(state)
            if state.frame == tamper:
                state = dataclasses.replace(state, hash=f"{int(state.hash, 16) ^ 1:016x}")
            if state.frame != lose:
                if gap := gaps.see(state.frame):
                    log.write_gap(*gap)
                log.write(keys.state(m), state.encode())
            for event in event_messages(game, m, "sim"):
                log.write(keys.event(m), event.encode())
            if game.done:
                break
            for status in script.statuses:
                if status.frame == state.frame:
                    log.write(keys.adapter(m), status.encode())
            for switch in script.switches:
                if switch.frame == state.frame:
                    log.write(keys.policy(m, switch.role), switch.encode())
                    players[switch.role].switch(switch.policy)
            senders = {role: f"{'human' if role == script.human else 'agent'}/{role}" for role in ROLES}
            answers = [players[role].act(state, senders[role]) for role in ROLES]
            for answer in answers:
                log.write(keys.action(m, answer.role), answer.encode())
            applied = tuple(a.action for a in answers)
            game.step(*applied)
        if summary:
            log.write(keys.summary(m), summary_message(game, m, "sim", {}, {}).encode())
    return published


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Recording, list[State]]:
    path = tmp_path_factory.mktemp("rec") / f"{M}.tsflog"
    states = record_match(path)
    return load(path), states


def test_load_counts(recorded: tuple[Recording, list[State]]) -> None:
    recording, states = recorded
    assert recording.clean and recording.undecodable == 0 and recording.gaps == []
    assert recording.start is not None and recording.start.seed == SEED
    assert recording.summary is not None and recording.summary.frame == FRAMES
    assert [s.frame for s in recording.states] == list(range(FRAMES + 1))
    assert recording.states == states
    assert len(recording.actions) == 2 * FRAMES
    assert [a.policy for _, a in recording.actions if a.role == "bait"] == ["circle"] * SWITCH_AT + [
        "idle"
    ] * (FRAMES - SWITCH_AT)
    assert [(s.frame, s.policy) for s in recording.switches] == [(SWITCH_AT, "idle")]
    assert recording.events and all(e.frame <= FRAMES for e in recording.events)
    assert sum(e.kind == "missile" for e in recording.events) == sum(
        c["missiles_fired"] for c in recording.summary.counters.values()
    )


def test_applied_actions_are_the_answers(recorded: tuple[Recording, list[State]]) -> None:
    recording, _ = recorded
    answers = {(a.frame, a.role): a.action for _, a in recording.actions}
    for state in recording.states[1:]:
        assert state.applied == [answers[(state.frame - 1, role)] for role in ROLES]


def test_replay_reproduces(recorded: tuple[Recording, list[State]]) -> None:
    assert replay(recorded[0]) == []


def test_replay_reports_tampered_frame(tmp_path: Path) -> None:
    path = tmp_path / "t.tsflog"
    record_match(path, tamper=17)
    assert replay(load(path)) == [17]


def test_lost_state_is_a_gap(tmp_path: Path) -> None:
    path = tmp_path / "g.tsflog"
    record_match(path, lose=20, summary=False)
    recording = load(path)
    assert recording.gaps == [(20, 20)] and recording.missing_frames == 1 and recording.summary is None
    with pytest.raises(ValueError, match="frame 20 is missing"):
        replay(recording)
    export(recording, tmp_path / "pq")
    tables = read(tmp_path / "pq", M)
    assert tables["gaps"].to_pydict() == {"match": [M], "first": [20], "last": [20]}
    assert tables["match"].to_pydict()["missing_frames"] == [1]
    assert tables["match"].to_pydict()["kills"] == [None]


def test_replay_needs_a_start(recorded: tuple[Recording, list[State]]) -> None:
    with pytest.raises(ValueError, match="no start record"):
        replay(dataclasses.replace(recorded[0], start=None))


def test_parquet_round_trip(recorded: tuple[Recording, list[State]], tmp_path: Path) -> None:
    recording, _ = recorded
    paths = export(recording, tmp_path / "out")
    assert set(paths) == set(TABLES) and all(p.exists() for p in paths.values())
    tables = {name: table.to_pydict() for name, table in read(tmp_path / "out", M).items()}
    states, actions = tables["states"], tables["actions"]

    assert len(states["frame"]) == len(recording.states)
    assert states["hash"] == [s.hash for s in recording.states]
    assert states["bait_obs"][10] == recording.states[10].obs["bait"]
    assert states["shooter_action"] == [s.applied[1] for s in recording.states]
    ship = states["shooter_ship"][5]
    assert [ship[k] for k in ("x", "y", "vx", "vy", "heading")] == recording.states[5].ships[1][:5]
    for role in ROLES:
        mine = [i for i, r in enumerate(actions["role"]) if r == role]
        assert [actions["action"][i] for i in mine] == [
            a.action for _, a in recording.actions if a.role == role
        ]
    received = read(tmp_path / "out", M)["actions"]["received"].cast("int64").to_pylist()
    assert received == [t for t, _ in recording.actions]  # UTC timestamps, to the nanosecond
    assert len(tables["events"]["kind"]) == len(recording.events)
    assert tables["switches"] == {
        "match": [M],
        "frame": [SWITCH_AT],
        "role": ["bait"],
        "policy": ["idle"],
        "reason": ["test"],
    }
    assert tables["gaps"] == {"match": [], "first": [], "last": []}
    assert recording.adapter == [ADAPTER]
    adapter = {name: values[0] for name, values in tables["adapter"].items()}
    assert (adapter["frame"], adapter["role"], adapter["partner"], adapter["policy"]) == (
        SWITCH_AT,
        "shooter",
        "B5",
        "S5",
    )
    assert (adapter["strategy"], adapter["window"], adapter["out_of_library"]) == ("cem", 20, False)
    assert dict(adapter["scores"]) == ADAPTER.scores and adapter["belief"] == []

    match = {name: values[0] for name, values in tables["match"].items()}
    assert len(tables["match"]["seed"]) == 1
    assert (match["match"], match["seed"], match["mode"]) == (M, SEED, "lockstep")
    assert (match["kills"], match["frames"]) == (recording.summary.kills, FRAMES)
    assert match["clean"] and match["missing_frames"] == 0
    assert GameConfig.from_dict(match["config"]) == GameConfig(frames=FRAMES)
