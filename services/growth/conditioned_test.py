"""The conditioned teammate's two parts: the env that tells it the group, and the network told one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")

from services.agent import library  # noqa: E402
from services.agent.networks import Network  # noqa: E402
from services.growth.conditioned import Told, told  # noqa: E402
from services.training.env import RecipeVecEnv  # noqa: E402
from shared.game import GameConfig  # noqa: E402


def test_a_network_told_a_belief_computes_what_the_conditioned_network_does_with_it_appended():
    rng = np.random.default_rng(0)
    features, groups = 7, 3
    arrays = {
        "w0": rng.normal(size=(5, features + groups)),
        "b0": rng.normal(size=5),
        "w1": rng.normal(size=(4, 5)),
        "b1": rng.normal(size=4),
    }
    x = rng.normal(size=(11, features))
    conditioned = Network(arrays, "tanh")
    for belief in (np.eye(groups)[2], np.array([0.2, 0.5, 0.3])):
        plain = Network(told(arrays, belief), "tanh")
        expected = conditioned(np.concatenate([x, np.tile(belief, (len(x), 1))], axis=1))
        np.testing.assert_allclose(plain(x), expected, atol=1e-12)


def test_each_game_sees_its_partners_group_and_a_finished_game_keeps_its_own():
    recipe = dataclasses.replace(library.registry()["B5"], partners=("S4", "S5", "S6"))
    env = Told(RecipeVecEnv(recipe, 16, GameConfig(frames=20)), np.array([1, 0, 1]))
    obs = env.reset()
    assert obs.shape == (16, env.venv.observation_space.shape[0] + 2)
    ended = 0
    for _ in range(25):  # past the 20-frame games' end: every lane ends once, some by death before
        groups = env.current()
        np.testing.assert_array_equal(obs[:, -2:], np.eye(2)[groups])
        obs, _, done, infos = env.step(np.zeros((16, 2), np.int64))
        for lane in np.flatnonzero(done):
            np.testing.assert_array_equal(infos[lane]["terminal_observation"][-2:], np.eye(2)[groups[lane]])
            ended += 1
    assert ended >= 16 and len(set(env.current().tolist())) == 2
