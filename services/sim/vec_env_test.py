"""The vectorised role env: one role's seat in lanes of the batched engine."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent.seats import policy_for
from services.sim import observation as ob
from services.sim.engine import Game
from services.sim.vec_env import RoleVectorEnv
from shared.game import GameConfig, join_action

SHORT = GameConfig().replace(frames=90)


def run(env: RoleVectorEnv, frames: int, seed: int = 0) -> list[tuple]:
    obs, _ = env.reset(seed=seed)
    rng, out = np.random.default_rng(seed), []
    for _ in range(frames):
        actions = rng.integers(0, 12, env.num_envs)
        out.append((actions, *env.step(actions)))
    return out


def test_rewards_are_team_points_and_games_restart_after_truncation() -> None:
    env = RoleVectorEnv(4, "shooter", policy_for("circle", "bait"), SHORT)
    env.reset(seed=1)
    first_seeds = env.batch.seeds.copy()
    games = [Game(SHORT, int(seed)) for seed in first_seeds]
    for frame in range(SHORT.frames):
        partner = env.partner_actions()
        actions = np.full(4, frame % 12)
        obs, rewards, terminated, truncated, infos = env.step(actions)
        for lane, game in enumerate(games):
            before = game.points
            game.step(int(partner[lane]), int(actions[lane]))
            assert rewards[lane] == game.points - before
        assert not terminated.any()
    assert truncated.all() and not (env.batch.seeds == first_seeds).all()
    final = infos["final_obs"]
    for lane, game in enumerate(games):
        np.testing.assert_array_equal(final[lane], ob.observe(game, "shooter"))
    assert (obs[:, ob.TIME] == 1.0).all()  # the new games' first frame


def test_same_seed_same_games_and_a_pool_plays_every_partner() -> None:
    pool = [policy_for(key, "shooter") for key in ("S4", "S5", "mirror")]
    a, b = (RoleVectorEnv(12, "bait", pool, SHORT, view="role") for _ in range(2))
    for (_, *one), (_, *two) in zip(run(a, 100), run(b, 100), strict=True):
        for x, y in zip(one[:4], two[:4], strict=True):
            np.testing.assert_array_equal(x, y)
    assert set(a.partner_of.tolist()) == {0, 1, 2}


def test_the_partner_must_play_the_other_seat() -> None:
    with pytest.raises(ValueError, match="plays bait, the seat being trained"):
        RoleVectorEnv(2, "bait", policy_for("circle", "bait"))


def test_with_end_on_death_the_learners_death_terminates_and_the_partners_truncates() -> None:
    env = RoleVectorEnv(32, "bait", policy_for("random", "shooter"), GameConfig(), end_on_death=True)
    env.reset(seed=3)
    ended = {"terminated": 0, "truncated": 0, "dead ship alive": 0}
    for frame in range(900):
        seeds = env.batch.seeds.copy()
        turn = 1 if frame % 50 == 0 else 0  # thrust on, turning now and then: into a border or the shield
        _, _, terminated, truncated, infos = env.step(np.full(32, join_action(turn, 1, 0)))
        assert not (terminated & truncated).any()
        for lane in np.flatnonzero(terminated | truncated):
            dead = ob.SELF if terminated[lane] else ob.PARTNER
            ended["dead ship alive"] += int(infos["final_obs"][lane][dead + ob.ALIVE] != 0.0)
            assert env.batch.seeds[lane] != seeds[lane]  # a new game
        ended["terminated"] += int(terminated.sum())
        ended["truncated"] += int(truncated.sum())
    assert ended["terminated"] > 50 and ended["truncated"] > 50
    # the last observation shows the ship that died dead, unless a round restarted in that frame
    assert ended["dead ship alive"] <= 0.01 * (ended["terminated"] + ended["truncated"]), ended
