"""The gateway core: input validation, key state -> action, rate limit, seats and tokens, the view."""

from __future__ import annotations

import json

import pytest

from services.human.core import (
    BURST,
    STRIKES,
    BadInput,
    Controls,
    RateLimit,
    SeatBook,
    action_keys,
    keys_action,
    parse,
    view,
)
from services.sim.engine import Game
from services.sim.match import state_message
from shared.game import DEATH_CAUSES, GameConfig, split_action
from shared.page import LINK_PARAMS, EventView, Keys, Watch, decode_down


def keys(**held: bool) -> Keys:
    return Keys(**{"left": False, "right": False, "thrust": False, "fire": False, **held})


def test_key_state_maps_to_the_action_encoding() -> None:
    assert keys_action(keys()) == 0
    assert keys_action(keys(fire=True)) == 1
    assert keys_action(keys(thrust=True)) == 2
    assert keys_action(keys(left=True)) == 4
    assert keys_action(keys(right=True, thrust=True, fire=True)) == 11
    assert keys_action(keys(left=True, right=True)) == 0  # both turns cancel
    for action in range(12):
        assert keys_action(action_keys(action)) == action
        turn, thrust, fire = split_action(action)
        assert action_keys(action).thrust == bool(thrust) and action_keys(action).fire == bool(fire)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("not json", "undecodable"),
        ("[1, 2]", "type"),
        ('{"type": "launch"}', "type"),
        ('{"type": "keys", "left": true}', "shape"),
        ('{"type": "keys", "left": 1, "right": false, "thrust": false, "fire": false}', "shape"),
        ('{"type": "keys", "left": true, "right": false, "thrust": false, "fire": false, "x": 1}', "shape"),
        ('{"type": "join", "role": "pilot", "token": "t"}', "shape"),
        ('{"type": "join", "role": "bait", "token": ""}', "shape"),
        ('{"type": "join", "role": "bait", "token": "' + "t" * 1100 + '"}', "too_large"),
        (b"\x00\x01", "binary"),
    ],
)
def test_bad_messages_are_refused_with_a_reason(text: str | bytes, reason: str) -> None:
    with pytest.raises(BadInput) as error:
        parse(text, ("join", "keys"))
    assert error.value.reason == reason


def test_a_message_type_is_only_taken_where_it_is_expected() -> None:
    join = json.dumps({"type": "join", "role": "bait", "token": "abc"})
    assert parse(join, ("join",)).role == "bait"
    with pytest.raises(BadInput):
        parse(join, ("ready", "keys"))
    assert parse('{"type": "watch"}', ("join", "watch")) == Watch()
    with pytest.raises(BadInput, match="shape"):
        parse('{"type": "watch", "role": "bait"}', ("join", "watch"))  # a spectator claims nothing


def test_controls_hold_the_latest_keys_and_count_drops() -> None:
    controls = Controls()
    assert controls.receive(keys(left=True, fire=True).encode())
    assert controls.action == 5 and not controls.ready
    assert controls.receive("garbage") is None
    assert controls.action == 5 and controls.drops == {"undecodable": 1}
    controls.receive('{"type": "ready"}')
    assert controls.ready


def test_rate_limit_allows_a_burst_then_the_rate() -> None:
    now = [0.0]
    limit = RateLimit(rate=10.0, burst=5, clock=lambda: now[0])
    assert [limit.allow() for _ in range(6)] == [True] * 5 + [False]
    now[0] += 0.1  # one message's worth
    assert limit.allow() and not limit.allow()
    now[0] += 100.0  # never more than the burst
    assert sum(limit.allow() for _ in range(20)) == 5


def test_a_flooding_connection_is_cut_off() -> None:
    now = [0.0]
    controls = Controls(limit=RateLimit(clock=lambda: now[0]))
    message = keys(thrust=True).encode()
    taken = [controls.receive(message) is not None for _ in range(BURST)]
    assert all(taken) and controls.action == 2
    with pytest.raises(BadInput) as error:
        for _ in range(STRIKES):
            controls.receive(keys(fire=True).encode())
    assert error.value.reason == "strikes"
    assert controls.action == 2  # nothing over the rate was played
    assert controls.drops == {"rate": STRIKES}


def test_a_seat_obeys_one_holder_with_the_right_token() -> None:
    book = SeatBook({"bait": "secret"})
    first, second = object(), object()
    assert "wrong seat token" in book.claim("bait", "guess", first)
    assert "not open to people" in book.claim("shooter", "secret", first)
    assert book.claim("bait", "secret", first) == ""
    assert "already taken" in book.claim("bait", "secret", second)
    book.release("bait", second)  # not the holder: nothing changes
    assert "already taken" in book.claim("bait", "secret", second)
    book.release("bait", first)
    assert book.claim("bait", "secret", second) == ""
    with pytest.raises(ValueError, match="unknown roles"):
        SeatBook({"pilot": "x"})


def test_view_carries_what_the_page_draws() -> None:
    game = Game(GameConfig(frames=60), seed=3)
    for _ in range(40):
        game.step(1, 5)  # bait fires, shooter turns left and fires
    state = state_message(game, "m1", "sim", (1, 5))
    frame = view(state)
    assert frame.frame == 40 and frame.frames == 60
    assert [s[:3] for s in frame.ships] == [
        [round(s.x, 1), round(s.y, 1), round(s.heading, 1)] for s in game.ships
    ]
    assert len(frame.missiles) == len(game.missiles) > 0
    assert {m[2] for m in frame.missiles} == {0, 1}  # both ships' missiles, by owner
    assert frame.fortress[0] == round(game.facing, 1)
    assert frame.applied == [1, 5]  # the page draws a thrusting ship's flame from these
    assert frame.respawn is None and frame.ending is False  # not narrated: nothing to say
    assert decode_down(frame.encode()) == frame  # what goes down the socket, as the page's contract reads it
    assert (
        "obs" not in json.loads(frame.encode())
        and view(state, obs=True, role="bait").obs == state.obs["bait"]
    )


def test_one_address_gets_its_burst_then_its_rate_and_others_are_untouched():
    from services.human.core import PerAddress

    now = [0.0]
    buckets = PerAddress(0.1, 3, clock=lambda: now[0])
    assert [buckets.allow("10.0.0.1") for _ in range(5)] == [True, True, True, False, False]
    assert buckets.allow("10.0.0.2")  # another address has a bucket of its own
    now[0] += 10.0  # one id per 10 s
    assert buckets.allow("10.0.0.1") and not buckets.allow("10.0.0.1")
    assert all(PerAddress(0.0, 3).allow("10.0.0.1") for _ in range(100))  # 0: no limit


def play(game: Game, bait: int, shooter: int, narrator, until) -> tuple[list[dict], list]:  # noqa: ANN001
    """Step `game` with fixed actions until `until(game)`: the narrated views and the events."""
    views, events = [], []
    while not until(game) and game.frame < game.config.frames:
        events += game.step(bait, shooter)
        views.append(view(state := state_message(game, "m", "sim", (bait, shooter)), narrator(state)))
    return views, events


def test_the_both_dead_count_down_reaches_zero_on_the_reset_frame() -> None:
    from services.human.core import Narrator

    game = Game(GameConfig(frames=600), seed=1)
    narrator = Narrator("bait", True, game.config.respawn_delay)
    # both ships thrust straight ahead, roughly at the fortress: both die, then the reset
    views, events = play(game, 2, 2, narrator, lambda g: any(e.kind == "reset" for e in g.events))
    deaths = [e for e in events if e.kind == "death"]
    assert {e.role for e in deaths} == {"bait", "shooter"} and all(e.detail in DEATH_CAUSES for e in deaths)
    reset = next(e.frame for e in events if e.kind == "reset")
    both_dead = max(e.frame for e in deaths)
    counts = {v.frame: v.respawn for v in views}
    assert counts[both_dead] == game.config.respawn_delay
    assert [counts[f] for f in range(both_dead, reset)] == list(range(game.config.respawn_delay, 0, -1))
    assert counts[reset] is None and counts[both_dead - 1] is None  # ships alive: no count-down


def test_the_partners_deliberate_round_end_is_narrated_only_for_an_agent_partner() -> None:
    from services.human.core import Narrator

    config = GameConfig(frames=900)
    told = {ends: Narrator("bait", ends, config.respawn_delay) for ends in (True, False)}
    game = Game(config, seed=2)
    play(game, 2, 0, lambda s: {}, lambda g: not g.bait.alive)  # the person's bait flies into the shield
    assert game.shooter.alive and game.fortress_alive
    state = state_message(game, "m", "sim", (2, 0))
    assert told[True](state)["ending"] and told[True](state)["respawn"] is None
    assert not told[False](state)["ending"]  # a person or an idle partner: nothing to announce
    shooter_seat = Narrator("shooter", True, config.respawn_delay)
    assert not shooter_seat(state)["ending"]  # the person's own ship lives
    assert not Narrator(None, True, config.respawn_delay)(state)["ending"]  # a spectator has no partner


def test_the_page_is_sent_the_events_it_shows() -> None:
    from services.human.core import event_view
    from shared.messages import GameEvent

    death = GameEvent(match="m", frame=7, sender="sim", kind="death", role="bait", detail="border")
    assert event_view(death) == EventView(frame=7, kind="death", role="bait", detail="border")
    assert event_view(GameEvent(match="m", frame=7, sender="sim", kind="missile", role="bait")) is None


def test_a_hello_carries_a_few_short_link_parameters_and_nothing_else():
    six = {f"P{i}": "v" * 40 for i in range(LINK_PARAMS)}
    assert parse(json.dumps({"type": "hello", "link": six}), ("hello",)).link == six
    for link in ({**six, "more": "x"}, {"STUDY_ID": 7}, {"STUDY_ID": ""}, {"x" * 65: "v"}, ["STUDY_ID"]):
        with pytest.raises(BadInput) as error:
            parse(json.dumps({"type": "hello", "link": link}), ("hello",))
        assert error.value.reason == "shape"
