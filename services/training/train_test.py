"""Smoke training: every algorithm of the library trains a few hundred steps, exports, and the
exported numpy network computes what the torch network does."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")

import torch as th  # noqa: E402

from services.agent import library, networks, seats  # noqa: E402
from services.agent.library_test import observations  # noqa: E402
from services.training.algorithms import HYPERPARAMETERS, make_model  # noqa: E402
from services.training.loop import prepare, train, whole_rollouts  # noqa: E402
from shared.errors import UsageError  # noqa: E402


@pytest.mark.parametrize("key", ["B1", "B5", "B6", "S1"])  # A2C, PPO, TRPO, double DQN
def test_smoke_training_exports_a_loadable_policy(tmp_path, key):
    root = tmp_path / "library"
    prepare(root)
    entry = train(key, root, steps=300, seed=0, run_dir=tmp_path / "runs", progress=False, score_games=1)
    assert entry["steps"] >= 300 and entry["score"]["games"] == 1 and entry["warm_start"] is None
    assert (tmp_path / "runs" / key / "curve.png").exists()
    policy = networks.load(key, root=root)
    p = policy.probs(observations(policy.role, policy.view)[0])
    assert p.min() > 0 and p.sum() == pytest.approx(1.0)


@pytest.mark.slow
@pytest.mark.long  # 11 s alone: kept out of the default run
def test_a_stopped_run_resumes_from_its_checkpoint(tmp_path):
    root, runs = tmp_path / "library", tmp_path / "runs"
    prepare(root)
    small = {**HYPERPARAMETERS["PPO"], "n_envs": 4, "n_steps": 16, "batch_size": 64}
    options = {"run_dir": runs, "hyperparameters": small, "every": 64, "progress": False, "score_games": 0}
    train("B5", root, steps=128, **options)
    curve = (runs / "B5" / "curve.csv").read_text().splitlines()
    entry = train("B5", root, steps=256, **options)
    resumed = (runs / "B5" / "curve.csv").read_text().splitlines()
    assert resumed[: len(curve)] == curve and len(resumed) > len(curve)  # the curve goes on
    assert entry["steps"] == 256 and entry["seconds"] >= json.loads(curve[-1].split(",")[1])
    train("B5", root, steps=128, **{**options, "hyperparameters": {**small, "learning_rate": 1e-3}})
    assert len((runs / "B5" / "curve.csv").read_text().splitlines()) == len(curve)  # other settings: anew


def test_the_steps_asked_are_rounded_up_to_whole_rollouts_so_the_bar_shows_what_is_played(tmp_path):
    """`tsf train --steps 4096` with PPO's 64 lanes of 128 steps plays one rollout, 8,192 steps: the
    bar's total says 8,192 too (it said 4,096 and ended at 8,192/4,096)."""
    root = tmp_path / "library"
    prepare(root)
    recipe = library.registry(root)["B5"]
    small = {**HYPERPARAMETERS["PPO"], "n_envs": 4, "n_steps": 16, "batch_size": 64}
    model = make_model(recipe, 0, small, root=root)
    assert [whole_rollouts(model, n) for n in (1, 64, 65, 100)] == [64, 64, 128, 128]
    entry = train("B5", root, steps=100, run_dir=tmp_path / "runs", hyperparameters=small, progress=False,
                  score_games=0)  # fmt: skip
    assert entry["steps"] == 128


def test_a_new_library_starts_as_a_copy_and_a_stray_directory_is_refused(tmp_path):
    prepare(tmp_path / "new")
    assert library.registry(tmp_path / "new").keys() == library.registry().keys()
    (tmp_path / "stray").mkdir()
    (tmp_path / "stray" / "notes.txt").write_text("mine")
    with pytest.raises(UsageError, match="--library"):
        prepare(tmp_path / "stray")


def test_a_recipe_trains_with_human_like_stand_ins_and_a_candidate_joins_a_library_of_its_own(tmp_path):
    """A candidate recipe (library.CANDIDATES) is trained only when named, into a library whose
    registry it joins; its partners may be calibrated stand-ins, which play their lanes' games as
    each lane restarts; any other kind of partner is refused with one clear line."""
    from dataclasses import replace

    from services.training.env import RecipeVecEnv

    assert "B10" in library.learned(["B10"]) and "B10" not in library.learned([])
    root = tmp_path / "library"
    prepare(root, ["B10"])
    recipe = library.registry(root)["B10"]
    assert recipe.partners[0] == "S4" and any(p.startswith("human(") for p in recipe.partners)
    prepare(root, ["B10"])  # once only
    assert (root / "registry.toml").read_text().count("[B10]") == 1
    env = RecipeVecEnv(replace(recipe, partners=("S4", "human(S5,skill=novice)")), 8, root=root)
    env.seed(1)
    env.reset()
    human = env.env.partners[1]
    restarted = 0
    for _ in range(400):
        env.step_async(np.array([env.action_space.sample() for _ in range(8)]))
        env.step_wait()
        restarted = max(restarted, int(human.partner.start.max()))
    assert set(env.env.partner_of.tolist()) == {0, 1} and restarted > 0
    lanes = np.flatnonzero(human.partner.start > 0)
    assert (human.partner.start[lanes] <= human.partner.t).all()
    with pytest.raises(UsageError, match="B10.partners"):
        RecipeVecEnv(replace(recipe, partners=("S4", "noisy(S5)")), 2, root=root)


@pytest.mark.parametrize("key", ["B4", "S2"])
def test_numpy_network_matches_torch(tmp_path, key):
    from services.training.algorithms import export

    recipe = library.registry()[key]
    model = make_model(recipe, seed=0)
    arrays = export(model, recipe)
    arrays.pop("meta")
    network = networks.Network(arrays, "relu" if recipe.algorithm == "DQN" else "tanh")
    features = np.stack(observations(recipe.role, recipe.view))[:, library.FEATURES[recipe.features]]
    with th.no_grad():
        x = th.as_tensor(features)
        if recipe.algorithm == "DQN":
            expected = model.policy.q_net(x).numpy()
        else:
            expected = model.policy.action_net(model.policy.mlp_extractor.forward_actor(x)).numpy()
    np.testing.assert_allclose(network(features), expected, rtol=1e-4, atol=1e-5)


def test_drawing_fire_pays_the_frames_the_fortress_opens_to_the_shooter_and_kills() -> None:
    from services.sim.batch import BatchGame
    from services.sim.observation import observe
    from services.sim.sampling import batch_act, lane_uniforms
    from services.training.rewards import drawing_fire_reward, opening

    bait, shooter = seats.policy_for("circle", "bait"), seats.policy_for("mirror", "shooter")
    batch = BatchGame(8, seeds=list(range(8)))
    paid = kills = 0.0
    for _ in range(1800):
        frame = batch.state.frame
        batch.step(
            *(
                batch_act(p, observe(batch, role, p.view), lane_uniforms(batch.seeds, seat, frame))
                for seat, (role, p) in enumerate([("bait", bait), ("shooter", shooter)])
            )
        )
        s, is_open = batch.state, opening(batch, 0)
        reward = drawing_fire_reward(batch, 0, s.points, {"kill": 10.0})
        assert (~is_open | ((s.lock == 0) & (s.vulnerable > 0) & s.fortress_alive)).all()
        np.testing.assert_array_equal(reward, is_open + 10.0 * batch.event_counts("kill"))
        paid += is_open.sum()
        kills += batch.event_counts("kill").sum()
    assert paid > 100 and kills > 10  # a competent pair opens the fortress and kills, and is paid


def test_the_shooter_is_paid_for_aiming_at_the_fortress_while_it_is_up() -> None:
    from services.sim.batch import BatchGame
    from services.training.rewards import shooter_position_reward

    batch = BatchGame(4, seeds=list(range(4)))
    s = batch.state
    s.x[:, 1], s.y[:, 1] = 300.0, 0.0  # on the +x axis, outside the region
    s.heading[:, 1] = [180.0, 200.0, 0.0, 180.0]  # at the fortress, 20 degrees off, away, at it
    s.fortress_alive[3] = False
    study = shooter_position_reward(batch, 1, s.points, {"kill": 10.0})
    paid = shooter_position_reward(batch, 1, s.points, {"kill": 10.0, "aim": 2.0}) - study
    np.testing.assert_allclose(paid, [2.0, 2.0 * np.cos(np.radians(20.0)) ** 16, 0.0, 0.0])


def test_the_events_reward_weighs_each_term_and_leaves_the_others_out() -> None:
    """The population's events partners are trained on random weightings of EVENT_TERMS."""
    from services.sim.batch import BatchGame
    from services.training.rewards import events_reward

    batch = BatchGame(3, seeds=list(range(3)))
    s = batch.state
    s.x[:, 0], s.y[:, 0] = [100.0, 300.0, 0.0], 0.0
    s.in_region[:, 0] = [True, False, True]
    reward = events_reward(batch, 0, s.points, {"region": 1.0, "distance": -0.5})
    np.testing.assert_allclose(reward, [1.0 - 0.25, -0.75, 1.0])
    assert (events_reward(batch, 0, s.points, {}) == 0.0).all()


def test_a_recipe_trains_with_any_policy_the_grammar_names(tmp_path):
    """A rule with its settings and a key of the libraries in use are partners as a library key
    is (what a best response to a population group trains with); a circle rule is a library entry."""
    from dataclasses import replace

    from services.agent.scripted import CircleBait
    from services.training.env import RecipeVecEnv

    root = tmp_path / "library"
    prepare(root)
    recipe = library.registry(root)["B5"]
    partners = ("mirror(placed_distance=30,max_speed=4)", "S4")
    env = RecipeVecEnv(replace(recipe, partners=partners), 2, root=root)
    rule = env.env.partners[0]
    assert rule.key == "mirror(placed_distance=30,max_speed=4)" and rule.placed_distance == 30.0
    library.record(
        root, {"GB9": {"role": "bait", "family": "circle", "description": "x", "rule": {"radius": 150.0}}}
    )
    circle = networks.load("GB9", root=root)
    assert isinstance(circle, CircleBait) and circle.radius == 150.0 and circle.key == "GB9"
