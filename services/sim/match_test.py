"""The sim's pure core: which action each seat plays, and the messages a frame produces."""

from __future__ import annotations

from services.sim.engine import Game
from services.sim.match import NOOP, Seats, event_messages, start_message, state_message, summary_message
from services.sim.observation import world_values
from shared.game import GameConfig
from shared.messages import Action, GameEvent, Start, State, Summary, decode

M = "m1"


def act(seats: Seats, role: str, frame: int, action: int) -> bool:
    return seats.offer(
        Action(match=M, frame=frame, sender="agent", role=role, action=action, policy="circle")
    )


def seated(*roles: str) -> Seats:
    seats = Seats()
    for role in roles:
        seats.arrive(role)
    return seats


def played(steps: int, seed: int = 4) -> Game:
    game = Game(GameConfig(frames=60), seed)
    for frame in range(steps):
        game.step(2 + 4 * (frame % 4 == 0), 1 + 8 * (frame % 6 == 0))
    return game


def test_empty_seats_play_noop() -> None:
    assert Seats().actions() == (NOOP, NOOP) == (0, 0)


def test_latest_action_kept_and_older_frame_ignored() -> None:
    seats = seated("bait", "shooter")
    assert act(seats, "bait", 3, 5)
    assert seats.actions() == (5, 0)
    assert act(seats, "bait", 4, 6) and act(seats, "shooter", 4, 9)
    assert seats.actions() == (6, 9)
    assert not act(seats, "bait", 3, 7)  # an answer to an older state arrives late
    assert seats.actions() == (6, 9) and seats.frame["bait"] == 4
    assert act(seats, "bait", 4, 8)  # a second answer to the same frame replaces the first
    assert seats.actions() == (8, 9)
    assert seats.actions() == (8, 9)  # no fresh action: the seat keeps its last one


def test_absent_seat_plays_noop() -> None:
    seats = seated("bait")
    assert act(seats, "shooter", 0, 9)  # taken, but nobody holds the seat
    assert not seats.present("shooter")
    assert seats.actions() == (0, 0)
    seats.arrive("shooter")
    assert seats.actions() == (0, 9)


def test_leave_resets_to_noop() -> None:
    seats = seated("bait", "shooter")
    act(seats, "bait", 1, 5)
    act(seats, "shooter", 1, 9)
    seats.leave("bait")
    assert seats.actions() == (0, 9)
    seats.arrive("bait")  # back: no-op until it answers again
    assert seats.actions() == (0, 9)
    act(seats, "bait", 2, 3)
    assert seats.actions() == (3, 9)


def test_multiple_players_per_seat() -> None:
    seats = seated("bait", "bait", "shooter")
    assert seats.players["bait"] == 2
    act(seats, "bait", 0, 5)
    seats.leave("bait")
    assert seats.present("bait") and seats.actions() == (5, 0)
    seats.leave("bait")
    assert not seats.present("bait") and seats.latest["bait"] == NOOP
    seats.leave("bait")  # never below zero
    assert seats.players["bait"] == 0
    seats.arrive("bait")
    assert seats.present("bait")


def test_answered_for_lockstep() -> None:
    assert Seats().answered(0)  # nobody to wait for
    seats = seated("bait", "shooter")
    assert not seats.answered(0)
    act(seats, "bait", 3, 1)
    assert not seats.answered(3)
    act(seats, "shooter", 3, 1)
    assert seats.answered(3) and seats.answered(2) and not seats.answered(4)
    act(seats, "bait", 4, 1)
    assert not seats.answered(4)
    seats.leave("shooter")  # a seat whose player is gone is not waited for
    assert seats.answered(4) and not seats.answered(5)


def test_state_message_matches_game() -> None:
    game = played(30)
    state = state_message(game, M, "sim", (6, 9))
    assert (state.match, state.frame, state.sender) == (M, game.frame, "sim")
    assert state.hash == game.state_hash()
    assert state.applied == [6, 9]
    assert state.obs == {role: world_values(game, role) for role in ("bait", "shooter")}
    assert (state.kills, state.points, state.frames) == (game.kills, game.points, 60)
    assert state.ships[0][:2] == [game.bait.x, game.bait.y] and state.ships[1][:2] == [
        game.shooter.x,
        game.shooter.y,
    ]
    assert state.fortress[0] == game.facing
    assert state.missiles == [list(m) for m in game.missiles] and state.missiles
    assert state.shells == [list(s) for s in game.shells]
    assert state.sent_ns > 0
    assert decode(state.encode(), State) == state


def test_state_message_of_first_frame() -> None:
    game = Game(GameConfig(frames=60), 4)
    state = decode(state_message(game, M, "sim", (0, 0)).encode(), State)
    assert state.frame == 0 and state.hash == game.state_hash() and state.applied == [0, 0]


def test_start_message_decodes() -> None:
    game = Game(GameConfig(frames=60), 11)
    policies = {"bait": "circle", "shooter": "mirror"}
    start = decode(start_message(game, M, "sim", "realtime", policies).encode(), Start)
    assert (start.frame, start.seed, start.mode, start.policies) == (0, 11, "realtime", policies)
    assert GameConfig.from_dict(start.config) == game.config


def test_summary_message_decodes() -> None:
    game = played(60)
    assert game.done
    summary = decode(
        summary_message(game, M, "sim", {"range": 3}, {"round_trip_ms_p50": 0.5}).encode(), Summary
    )
    assert (summary.frame, summary.kills, summary.points) == (60, game.kills, game.points)
    assert summary.kills_per_minute == game.kills_per_minute()
    assert summary.counters == game.counters()
    assert summary.drops == {"range": 3} and summary.timing == {"round_trip_ms_p50": 0.5}


def test_event_messages_follow_game_events() -> None:
    game, seen = Game(GameConfig(frames=60), 4), []
    for _ in range(20):
        game.step(0, 1)  # the shooter fires whenever it can
        messages = event_messages(game, M, "sim")
        assert [(m.frame, m.kind, m.role, m.detail) for m in messages] == [tuple(e) for e in game.events]
        seen += [decode(m.encode(), GameEvent) for m in messages]
    assert any(e.kind == "missile" and e.role == "shooter" for e in seen)


def test_the_state_reads_both_seats_views_as_each_alone_would() -> None:
    """state_message reads the game once for both seats (world_views): the same values, every frame."""
    for steps in range(0, 61, 3):
        game = played(steps, seed=steps)
        obs = state_message(game, M, "sim", (0, 0)).obs
        assert obs == {role: world_values(game, role) for role in ("bait", "shooter")}
