import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test, seed_test
from pettingzoo.test.render_test import collect_render_results

from services.agent import envs  # importing it registers tsf/Role-v0
from services.agent.scripted import MirrorShooter
from services.sim.env import RoleEnv
from services.sim.vec_env import RoleVectorEnv
from shared.game import GameConfig

SHORT = GameConfig(frames=120)


@pytest.mark.filterwarnings("ignore:.*Not able to test alternative render modes")
@pytest.mark.parametrize(
    ("role", "partner"), [("bait", "S5"), ("shooter", "circle"), ("bait", MirrorShooter())]
)
def test_the_registered_id_makes_a_role_env_that_passes_the_checker(role, partner):
    env = gymnasium.make(envs.ENV_ID, role=role, partner=partner, config=SHORT, render_mode="rgb_array")
    assert isinstance(env.unwrapped, RoleEnv) and env.unwrapped.role == role
    assert env.unwrapped.partner.role != role
    check_env(env.unwrapped)
    env.reset(seed=1)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3


def test_a_partner_that_cannot_play_the_other_seat_is_refused_by_name():
    with pytest.raises(Exception, match="B5"):
        gymnasium.make(envs.ENV_ID, role="bait", partner="B5")


def test_make_vec_gives_the_batched_env_with_the_same_games_as_building_it():
    made = gymnasium.make_vec(envs.ENV_ID, num_envs=4, role="bait", partner=["S5", "mirror"], config=SHORT)
    assert isinstance(made, RoleVectorEnv) and made.num_envs == 4 and len(made.partners) == 2
    direct = RoleVectorEnv(4, "bait", [envs._partner("S5", "bait"), MirrorShooter()], SHORT)
    traces = []
    for vec in (made, direct):
        obs, _ = vec.reset(seed=3)
        rng = np.random.default_rng(0)
        trace = [obs]
        for _ in range(SHORT.frames + 5):  # past one autoreset
            obs, reward, _, truncated, _ = vec.step(rng.integers(12, size=4))
            assert vec.single_observation_space.contains(obs[0])
            trace += [obs, reward, truncated]
        traces.append(trace)
    assert all(np.array_equal(a, b) for a, b in zip(*traces, strict=True))


def test_the_pettingzoo_factories_pass_pettingzoo_checks():
    api_test(envs.env(config=SHORT), num_cycles=SHORT.frames + 10)
    parallel_api_test(envs.parallel_env(config=SHORT), num_cycles=SHORT.frames + 10)
    seed_test(lambda: envs.env(config=SHORT), num_cycles=30)
    # render_test() opens a "human" window first; the rgb_array half of it, as it checks it:
    for frame in collect_render_results(envs.env(config=SHORT, render_mode="rgb_array")):
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert envs.raw_env().metadata["name"] == "tsf_v0" and envs.env().metadata["is_parallelizable"]


def test_no_service_imports_gymnasium():
    """Only this module loads gymnasium (and registers the id): a live service never pays for it,
    nor for numba (the bulk engine's)."""
    code = (
        "import sys, services.sim.service, services.agent.service, services.adapter.service, "
        "services.recorder.service, services.study.runner\n"
        "assert not {'gymnasium', 'numba'} & set(sys.modules), 'gymnasium or numba imported'\n"
        "import services.commands.app, services.evaluation.evaluation\n"
        "assert 'gymnasium' not in sys.modules, 'gymnasium imported'\n"
        "from services.agent import envs\n"
        "import gymnasium\n"
        "assert envs.ENV_ID in gymnasium.envs.registration.registry\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
