import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test

from services.agent.policy import UniformPolicy
from services.agent.scripted import CircleBait, Idle, MirrorShooter
from services.sim import observation
from services.sim.engine import Game
from services.sim.env import RoleEnv, TSFParallelEnv
from services.sim.observation import VIEWS, observe
from services.sim.play import play
from shared.game import OBS_SIZE, GameConfig

SHORT = GameConfig(frames=200)


@pytest.mark.parametrize("view", VIEWS)
def test_parallel_env_passes_the_pettingzoo_api_test(view):
    parallel_api_test(TSFParallelEnv(SHORT, view=view), num_cycles=SHORT.frames + 10)
    parallel_seed_test(lambda: TSFParallelEnv(SHORT, view=view), num_cycles=50)


@pytest.mark.filterwarnings("ignore:.*Not able to test alternative render modes")
@pytest.mark.parametrize(("role", "partner"), [("bait", MirrorShooter()), ("shooter", CircleBait())])
def test_role_env_passes_the_gymnasium_checker(role, partner):
    check_env(RoleEnv(role, partner, SHORT, render_mode="rgb_array"))


def test_same_seed_and_actions_give_the_same_observations():
    runs = []
    for _ in range(2):
        env = TSFParallelEnv(SHORT, view="role")
        rng = np.random.default_rng(1)
        obs, _ = env.reset(seed=5)
        trace = [obs["bait"], obs["shooter"]]
        obs, _ = env.reset()  # an unseeded reset after a seeded one replays too
        while env.agents:
            obs, _, _, _, infos = env.step({role: int(rng.integers(12)) for role in env.agents})
            trace += [obs["bait"], obs["shooter"], infos["bait"]["state_hash"]]
        runs.append(trace)
    assert all(np.array_equal(a, b) for a, b in zip(*runs, strict=True))


def test_a_full_game_truncates_at_its_last_frame_and_rewards_the_points_change():
    env = TSFParallelEnv()
    bait, shooter = CircleBait(), MirrorShooter()
    obs, _ = env.reset(seed=0)
    bait.reset(1)
    shooter.reset(2)
    frames = total = kills = 0
    while env.agents:
        before = env.game.points
        actions = {"bait": bait.act(obs["bait"]), "shooter": shooter.act(obs["shooter"])}
        obs, rewards, terminations, truncations, infos = env.step(actions)
        frames += 1
        assert rewards == {"bait": env.game.points - before, "shooter": env.game.points - before}
        assert not any(terminations.values())
        assert all(truncations.values()) == (frames == 1800) == (env.agents == [])
        total += rewards["bait"]
        kills += sum(event["kind"] == "kill" for event in infos["shooter"]["events"])
    assert frames == 1800 and total == env.game.points
    assert kills == env.game.kills == play(CircleBait(), MirrorShooter(), seed=0).kills > 0
    with pytest.raises(ValueError, match="game is over"):
        env.step({"bait": 0, "shooter": 0})


def test_role_env_trains_one_seat_against_a_partner_and_replays_play():
    env = RoleEnv("bait", MirrorShooter())
    bait = CircleBait()
    obs, _ = env.reset(seed=0)
    bait.reset(1)  # the seed play() gives the bait
    truncated = False
    while not truncated:
        obs, reward, terminated, truncated, info = env.step(bait.act(obs))
        assert not terminated
    assert env.game.frame == 1800
    assert env.game.kills == play(CircleBait(), MirrorShooter(), seed=0).kills > 0


def test_role_env_reads_the_partner_in_its_own_view_and_uses_a_custom_reward():
    partner = UniformPolicy("bait")
    partner.view = "role"
    seen = []
    partner.act = lambda obs: seen.append(obs) or 0
    env = RoleEnv("shooter", partner, reward=lambda game, role, events: len(events) + 0.5)
    env.reset(seed=3)
    _, reward, *_ = env.step(3)  # the shooter fires: one missile event
    assert reward == 1.5
    expected = observe(env.game, "bait", "role")
    env.step(0)
    assert np.array_equal(seen[-1], expected)


def test_observations_stay_inside_the_space_through_border_deaths():
    for view in VIEWS:
        env = RoleEnv("bait", Idle("shooter"), view=view)
        obs, _ = env.reset(seed=0)
        borders = 0
        for step in range(600):
            obs, _, _, _, info = env.step(2 if step % 60 > 10 else 6)  # thrust, now and then turning
            assert obs in env.observation_space
            borders += sum(e["detail"] == "border" for e in info["events"])
        assert borders > 0


def test_invalid_actions_and_wrong_seats_raise():
    env = TSFParallelEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action for shooter"):
        env.step({"bait": 0, "shooter": 12})
    role_env = RoleEnv("bait", MirrorShooter())
    role_env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action for bait"):
        role_env.step(1.5)
    with pytest.raises(ValueError, match="invalid action for bait"):
        role_env.step(np.array(12))
    with pytest.raises(ValueError, match="plays bait"):
        RoleEnv("bait", CircleBait())


def test_an_action_as_sb3_predicts_it_is_played_as_the_integer():
    """SB3's `model.predict` answers a Discrete action as a 0-d integer array; the step takes it."""
    games = [RoleEnv("bait", MirrorShooter()) for _ in range(2)]
    for env in games:
        env.reset(seed=3)
    for step in range(90):
        action = 2 if step % 30 > 5 else 6
        as_array, as_int = games[0].step(np.array(action, np.int64)), games[1].step(action)
        assert np.array_equal(as_array[0], as_int[0]) and as_array[1:4] == as_int[1:4]
    with pytest.raises(ValueError, match="observation view"):
        TSFParallelEnv(view="fortress")


def test_render_gives_an_image_only_in_rgb_array_mode():
    env = TSFParallelEnv(render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().shape == (627, 711, 3)
    plain = TSFParallelEnv()
    plain.reset(seed=0)
    assert plain.render() is None


def test_the_observation_layout_fills_the_contracts_size():
    assert observation.TIME + 1 == OBS_SIZE
    assert observe(Game(SHORT, 1), "bait").shape == (OBS_SIZE,)
