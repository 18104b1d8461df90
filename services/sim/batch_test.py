"""The differential test: the batched engine plays the reference engine's games (the scalar
`Game`); per-frame state hashes and events agree.

The default run checks a sample of seeded games; `-m slow` runs the full differential test
(200 games with random actions, 50 with library policies, every frame of each)."""

from __future__ import annotations

import itertools
import math
import random

import numpy as np
import pytest

from services.agent.library import keys
from services.agent.seats import policy_for
from services.sim import observation as ob
from services.sim.batch import BatchGame, Rules, _point_distance
from services.sim.engine import Game
from services.sim.play import play
from shared.game import ROLES, GameConfig


def assert_same_games(seeds: list[int], streams: np.ndarray, config: GameConfig | None = None) -> None:
    """Play each seed's action stream (frames, 2) in a scalar Game and in one lane of a batch, and
    compare every frame's state hash, events and, at the end, the counters."""
    batch = BatchGame(len(seeds), config, seeds)
    games = [Game(config, seed) for seed in seeds]
    for frame in range(streams.shape[1]):
        batch.step(streams[:, frame, 0], streams[:, frame, 1])
        for lane, game in enumerate(games):
            events = game.step(*(int(a) for a in streams[lane, frame]))
            assert batch.state_hash(lane) == game.state_hash(), (seeds[lane], frame + 1)
            assert batch.events(lane) == events, (seeds[lane], frame + 1)
    for lane, game in enumerate(games):
        assert batch.counters(lane) == game.counters()
        assert batch.kills_per_minute()[lane] == game.kills_per_minute()


def random_streams(seeds: list[int], frames: int) -> np.ndarray:
    return np.stack([np.random.default_rng(abs(seed)).integers(0, 12, (frames, 2)) for seed in seeds])


def recorder(actions: list[tuple[int, int]]):
    return lambda game, bait, shooter: actions.append((bait, shooter))


def library_streams(seeds: list[int]) -> np.ndarray:
    """Action streams of scalar games between library pairs (every pair in turn), which kill the
    fortress, lose ships to every cause and reset, unlike random play."""
    pairs = itertools.cycle(itertools.product(keys("bait"), keys("shooter")))
    streams = []
    for seed in seeds:
        bait, shooter = next(pairs)
        actions: list[tuple[int, int]] = []
        play(policy_for(bait, "bait"), policy_for(shooter, "shooter"), seed, trace=recorder(actions))
        streams.append(actions)
    return np.array(streams)


def test_random_games_are_the_scalar_games() -> None:
    seeds = list(range(12))
    assert_same_games(seeds, random_streams(seeds, 1800))


def test_library_games_are_the_scalar_games_with_kills_deaths_and_resets() -> None:
    seeds = [3, 17, 29]
    streams = library_streams(seeds)
    batch = BatchGame(len(seeds), seeds=seeds)
    assert_same_games(seeds, streams)
    for frame in range(streams.shape[1]):
        batch.step(streams[:, frame, 0], streams[:, frame, 1])
    assert batch.state.kills.sum() > 0


@pytest.mark.slow
def test_200_random_games_are_the_scalar_games() -> None:
    for start in range(0, 200, 50):
        seeds = list(range(1000 + start, 1050 + start))
        assert_same_games(seeds, random_streams(seeds, 1800))


@pytest.mark.slow
def test_50_library_games_are_the_scalar_games() -> None:
    seeds = list(range(500, 550))
    assert_same_games(seeds, library_streams(seeds))


def test_other_rules_and_big_negative_seeds_are_the_scalar_games() -> None:
    config = GameConfig().replace(frames=600, shell_speed=3.0, fortress_fire_interval=5, missiles_in_flight=2)
    seeds = [-7, 2**40 + 3, 0]
    assert_same_games(seeds, random_streams(seeds, 600), config)


def test_point_queries_are_pymunks() -> None:
    """The hexagon distance is pymunk's to the last bit, at any facing, inside and out."""
    rng = random.Random(0)
    for _ in range(300):
        game = Game(seed=0)
        game._set_facing(rng.uniform(0.0, 360.0))
        rules = Rules.of(game.config)
        for _ in range(20):
            angle, dist = rng.uniform(0, 2 * math.pi), rng.uniform(0.0, 260.0)
            x, y = dist * math.cos(angle), dist * math.sin(angle)
            for planes, poly in ((rules.shield_planes, game.shield), (rules.region_planes, game.region)):
                assert _point_distance(planes, game.facing, x, y) == poly.point_query((x, y)).distance


def test_resetting_some_lanes_starts_their_games_afresh_and_leaves_the_others() -> None:
    seeds = [5, 6, 7]
    streams = random_streams(seeds, 300)
    batch = BatchGame(3, seeds=seeds)
    for frame in range(200):
        batch.step(streams[:, frame, 0], streams[:, frame, 1])
    batch.reset([1], [42])
    kept, fresh = Game(seed=5), Game(seed=42)
    for frame in range(200):
        kept.step(*(int(a) for a in streams[0, frame]))
    for frame in range(200, 300):
        batch.step(streams[:, frame, 0], streams[:, frame, 1])
        kept.step(*(int(a) for a in streams[0, frame]))
        fresh.step(*(int(a) for a in streams[1, frame]))
    assert batch.state_hash(0) == kept.state_hash()
    assert batch.state_hash(1) == fresh.state_hash()


@pytest.mark.parametrize(
    ("bait", "shooter", "message"),
    [
        ([0, 12, 0], [0, 0, 0], "invalid action for bait in lane 1: 12"),
        ([0, 0, 0], [0, 0, -1], "invalid action for shooter in lane 2: -1"),
        ([0, 0], [0, 0, 0], r"bait actions: expected shape \(3,\), got \(2,\)"),
        ([0, 0, 0], [0.0, 1.0, 2.0], "shooter actions: expected integers"),
        ([0, 0, 0], [[0, 0, 0]], r"shooter actions: expected shape \(3,\), got \(1, 3\)"),
        (np.array([0, 0, 200], np.uint8), [0, 0, 0], "invalid action for bait in lane 2: 200"),
        ([0, 0, 0], [True, False, True], "shooter actions: expected integers 0..11, got dtype bool"),
    ],
)
def test_bad_actions_raise_naming_lane_role_and_value_and_change_no_lane(bait, shooter, message) -> None:
    batch = BatchGame(3)
    batch.step(np.full(3, 3), np.full(3, 9))
    before = [batch.state_values(lane) for lane in range(3)]
    with pytest.raises(ValueError, match=message):
        batch.step(np.asarray(bait), np.asarray(shooter))
    assert [batch.state_values(lane) for lane in range(3)] == before


def test_a_finished_game_refuses_more_frames() -> None:
    batch = BatchGame(2, GameConfig().replace(frames=3))
    for _ in range(3):
        batch.step(np.zeros(2, int), np.zeros(2, int))
    assert batch.done.all()
    with pytest.raises(ValueError, match="game is over after 3 frames"):
        batch.step(np.zeros(2, int), np.zeros(2, int))


def test_a_games_observations_are_its_lanes_in_both_views() -> None:
    """observe runs in Python for a Game and compiled for a batch: the same values either way."""
    seeds = [11, 12]
    streams = library_streams(seeds)
    batch, games = BatchGame(2, seeds=seeds), [Game(seed=seed) for seed in seeds]
    for frame in range(streams.shape[1]):
        for role, view in itertools.product(ROLES, ob.VIEWS):
            expected = np.stack([ob.observe(game, role, view) for game in games])
            np.testing.assert_array_equal(ob.observe(batch, role, view), expected)
        batch.step(streams[:, frame, 0], streams[:, frame, 1])
        for lane, game in enumerate(games):
            game.step(*(int(a) for a in streams[lane, frame]))
