import dataclasses
import random

from services.sim.engine import Game
from services.sim.lanes import Lanes
from services.sim.match import event_messages, start_message, state_message, summary_message
from shared.game import GameConfig

POLICIES = {"bait": "", "shooter": ""}


def same(message: object) -> bytes:
    """A message's record, less the time a state was put (sent_ns)."""
    if hasattr(message, "sent_ns"):
        message = dataclasses.replace(message, sent_ns=0)
    return message.encode()


def test_lanes_give_each_match_the_messages_its_own_game_gives() -> None:
    """Matches that step on different frames, one freed and its lane taken by a new match, the
    engine grown as they come: every message is the one a Game of its own gives, byte for byte."""
    lanes, config, rng = Lanes(), GameConfig(frames=300), random.Random(1)
    games, played = [], []
    for seed in range(5):  # the engine grows from one lane to eight
        games.append(Game(config, 10 + seed))
        played.append(lanes.take(config, 10 + seed))
    for game, lane in zip(games, played, strict=True):
        assert same(start_message(game, "m", "sim", "lockstep", POLICIES)) == same(
            start_message(lane, "m", "sim", "lockstep", POLICIES)
        )
    for frame in range(300):
        due = [k for k in range(5) if rng.random() < 0.7 and not games[k].done]
        for k in due:
            actions = (rng.randrange(12), rng.randrange(12))
            games[k].step(*actions)
            played[k].play(actions)
        lanes.step()
        for k in due:
            game, lane = games[k], played[k]
            assert same(state_message(game, "m", "sim", (0, 0))) == same(
                state_message(lane, "m", "sim", (0, 0))
            )
            assert [same(e) for e in event_messages(game, "m", "sim")] == [
                same(e) for e in event_messages(lane, "m", "sim")
            ]
        if frame == 150:  # a match ends; the next takes its lane
            played[2].free()
            games[2], played[2] = Game(config, 99), lanes.take(config, 99)
            assert played[2].lane == 2
    assert lanes.engines[config].game.n == 8
    for game, lane in zip(games, played, strict=True):
        assert same(summary_message(game, "m", "sim", {}, {})) == same(
            summary_message(lane, "m", "sim", {}, {})
        )


def test_matches_of_other_lengths_play_on_engines_of_their_own() -> None:
    lanes = Lanes()
    short, long = lanes.take(GameConfig(frames=2), 1), lanes.take(GameConfig(frames=9), 1)
    assert short.engine is not long.engine and (short.lane, long.lane) == (0, 0)
    for _ in range(2):
        short.play((0, 0))
        long.play((0, 0))
        lanes.step()
    assert short.done and not long.done and (short.frame, long.frame) == (2, 2)
