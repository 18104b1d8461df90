"""Bring your own policy: an SB3 model trained on the registered env plays where a library key does,
with exact probabilities, and `tsf library add` exports it into a library of the user's."""

import json
import os
import subprocess
import sys

import gymnasium
import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")

import torch as th  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402

from services.agent import envs, library, outside
from services.agent.networks import FLOOR
from services.agent.player import Player
from services.agent.seats import policy_for
from services.commands.app import app
from services.commands.entry import run
from services.sim.engine import Game
from services.sim.match import state_message
from services.sim.observation import observe
from services.sim.play import play
from shared.errors import UsageError
from shared.game import GameConfig
from shared.messages import decode_any


@pytest.fixture(scope="module")
def model_zip(tmp_path_factory):
    """The docs' worked example, tiny: a bait trained against S5 for a few hundred steps."""
    env = gymnasium.make(envs.ENV_ID, role="bait", partner="S5", config=GameConfig(frames=100))
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=128)
    path = tmp_path_factory.mktemp("model") / "my_bait.zip"
    model.save(path)
    return path, model


def sb3_probs(model, obs):
    with th.no_grad():
        p = model.policy.get_distribution(th.as_tensor(obs[None])).distribution.probs[0].numpy()
    return (1 - FLOOR) * p.astype(np.float64) + FLOOR / 12


def observations(n=50):
    game, rows = Game(seed=4), []
    rng = np.random.default_rng(0)
    for _ in range(n):
        rows.append(observe(game, "bait", "world"))
        game.step(int(rng.integers(12)), int(rng.integers(12)))
    return np.array(rows)


def test_a_zip_plays_a_seat_with_the_models_exact_distribution(model_zip):
    path, model = model_zip
    policy = policy_for(str(path), "bait")
    rows = observations()
    expected = np.array([sb3_probs(model, obs) for obs in rows])
    assert np.allclose(policy.probs_batch(rows), expected, atol=1e-6)
    assert np.allclose(policy.probs(rows[7]), expected[7], atol=1e-6)
    assert np.allclose(policy.probs_batch(rows).sum(axis=1), 1.0)
    policy.reset(3)  # act draws from those probabilities: frequencies match on one observation
    counts = np.bincount([policy.act(rows[0]) for _ in range(4000)], minlength=12) / 4000
    assert np.abs(counts - expected[0]).max() < 0.03
    result = play(policy, policy_for("S5", "shooter"), 0, GameConfig(frames=200))
    assert result.frames == 200


def test_a_zip_is_named_in_messages_by_its_file_name(model_zip):
    path, _ = model_zip
    long = path.parent / ("x" * 40) / "my_bait.zip"
    assert outside.record_name(str(long)) == "my_bait.zip" == policy_for(str(path), "bait").key
    assert outside.record_name("S5") == "S5"
    assert outside.record_name("services.agent.scripted:CircleBait") == "services.agent.scripted:CircleBait"
    assert outside.record_name("my_lab." + "deeply_nested." * 5 + "policies:CircleBait") == "CircleBait"
    player = Player("bait", str(path), seed=1)
    state = state_message(Game(seed=1), "m", "sim", (0, 0))
    assert decode_any(player.act(state, "agent/bait").encode()).policy == "my_bait.zip"


def test_a_zip_or_object_is_refused_with_one_line_when_it_cannot_play(tmp_path, model_zip):
    with pytest.raises(UsageError, match="no such file"):
        policy_for(str(tmp_path / "missing.zip"), "bait")
    (tmp_path / "bad.zip").write_bytes(b"not a zip")
    with pytest.raises(UsageError, match="not a Stable-Baselines3 model"):
        policy_for(str(tmp_path / "bad.zip"), "bait")
    with pytest.raises(UsageError, match="plays shooter, not bait"):
        policy_for("services.agent.scripted:MirrorShooter", "bait", "--bait")
    assert policy_for("services.agent.scripted:CircleBait", "bait").role == "bait"


def test_library_add_exports_into_a_library_of_the_users_that_tsf_library_lists(
    tmp_path, model_zip, monkeypatch, capsys
):
    path, model = model_zip
    mine = tmp_path / "mylib"
    shipped = library.manifest_hash()
    args = ["library", "add", "MYBAIT", str(path), "--role", "bait", "--library", str(mine), "--games", "1"]
    assert run(app, args) == 0
    entry = library.manifest(mine)["MYBAIT"]
    assert entry["sha256"] == library.file_hash(mine / entry["file"])
    assert entry["source"]["sha256"] == library.file_hash(path)
    assert entry["provenance"]["library"] == shipped and entry["provenance"]["command"].startswith("tsf")
    assert entry["score"]["partner"] == "S5" and entry["score"]["games"] == 1
    assert library.manifest_hash() == shipped  # nothing enters the shipped library
    assert "MYBAIT" not in library.registry()

    monkeypatch.setenv("TSF_LIBRARY", str(mine))
    assert library.keys("bait")[-1] == "MYBAIT" and library.manifest_hash() != shipped
    rows = observations()
    added = policy_for("MYBAIT", "bait")
    assert np.allclose(added.probs_batch(rows), [sb3_probs(model, obs) for obs in rows], atol=1e-6)
    capsys.readouterr()
    assert run(app, ["game", "--bait", "MYBAIT", "--shooter", "S5", "--frames", "100"]) == 0
    assert "kills" in capsys.readouterr().out
    assert run(app, ["library", "add", "MYBAIT", str(path), "--role", "bait", "--library", str(mine)]) == 2
    shipped_dir = str(library.LIBRARY)
    assert run(app, ["library", "add", "X", str(path), "--role", "bait", "--library", shipped_dir]) == 2
    assert "X" not in json.loads((library.LIBRARY / "manifest.json").read_text())


def test_with_a_library_of_yours_the_table_is_in_its_directory(tmp_path):
    (tmp_path / "registry.toml").write_text("")
    code = "from services.table.table import DEFAULT_TABLE; print(DEFAULT_TABLE)"
    env = os.environ | {"TSF_LIBRARY": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == str(tmp_path / "table.json")
