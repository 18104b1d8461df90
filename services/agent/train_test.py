"""Smoke training: every algorithm of the library trains a few hundred steps, exports, and the
exported numpy network computes what the torch network does."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")

import torch as th  # noqa: E402

from services.agent import library  # noqa: E402
from services.agent.library_test import observations  # noqa: E402
from services.agent.train import make_model, train  # noqa: E402


@pytest.mark.parametrize("key", ["B1", "B5", "B6", "S1"])  # A2C, PPO, TRPO, double DQN
def test_smoke_training_exports_a_loadable_policy(tmp_path, key):
    root = tmp_path / "library"
    root.mkdir()
    shutil.copy(library.LIBRARY / "registry.toml", root)
    entry = train(key, steps=300, seed=0, log_dir=tmp_path / "logs", out=root, progress=False, score_games=1)
    assert entry["steps"] == 300 and entry["score"]["games"] == 1
    assert (tmp_path / "logs" / "progress.csv").exists()
    policy = library.load(key, root=root)
    p = policy.probs(observations(policy.role, policy.view)[0])
    assert p.min() > 0 and p.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("key", ["B4", "S2"])
def test_numpy_network_matches_torch(tmp_path, key):
    from services.agent.train import export

    recipe = library.registry()[key]
    model = make_model(recipe, seed=0, log_dir=None)
    arrays = export(model, recipe)
    arrays.pop("meta")
    network = library.Network(arrays, "relu" if recipe.algorithm == "DQN" else "tanh")
    features = np.stack(observations(recipe.role, recipe.view))[:, library.FEATURES[recipe.features]]
    with th.no_grad():
        x = th.as_tensor(features)
        if recipe.algorithm == "DQN":
            expected = model.policy.q_net(x).numpy()
        else:
            expected = model.policy.action_net(model.policy.mlp_extractor.forward_actor(x)).numpy()
    np.testing.assert_allclose(network(features), expected, rtol=1e-4, atol=1e-5)
