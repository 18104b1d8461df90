"""The env a recipe trains in: the learned heads of one recipe over lanes of the batched engine, as
SB3's vectorised env (`RecipeVecEnv`), with the recipe's reward (rewards.py) and partners."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from services.agent import library, networks
from services.agent.library import FEATURES, LIBRARY, Recipe
from services.agent.networks import HEAD_SIZES, HEADS
from services.population.human_like import HumanLike
from services.population.partners import HumanLanes, make_partner
from services.sim.vec_env import RoleVectorEnv
from services.training.rewards import REWARDS
from shared.errors import UsageError
from shared.game import GameConfig, Policy, join_action, other


def recipe_partner(name: str, recipe: Recipe, config: GameConfig, root: Path):  # noqa: ANN201
    """One of a recipe's partners by name: a key of the library at `root` plays as that library
    plays it; any other policy the partner grammar names (a key of the libraries in use, a rule
    with its settings: `mirror(placed_distance=30)`) plays as itself, in batch; a calibrated
    human-like stand-in (`human(B5,skill=novice)`, population/partners.py) plays in its batched form,
    stateful per lane. Anything else (a wrapper, a plug-in) is a UsageError."""
    if name in library.registry(root):
        return networks.load(name, config, root)
    partner = make_partner(name, other(recipe.role))
    if isinstance(partner, HumanLike):
        return HumanLanes(partner)
    if not hasattr(partner, "probs_batch"):
        problem = "a recipe's partner is a library key, a rule, or human(...)"
        raise UsageError(f"{recipe.key}.partners", name, problem)
    return partner


def curve_partner(recipe: Recipe, root: Path) -> Policy:
    """The partner of a recipe's curve and score: its first partner that is a policy (not a
    stand-in)."""
    for name in recipe.partners:
        partner = recipe_partner(name, recipe, GameConfig(), root)
        if not isinstance(partner, HumanLanes):
            return partner
    raise UsageError(f"{recipe.key}.partners", ", ".join(recipe.partners), "name no policy")


class RecipeVecEnv(VecEnv):
    """The learned heads of one recipe over lanes of the batched engine, as SB3's vectorised env:
    the observation is the recipe's feature set, the action the learned heads (Discrete for one,
    MultiDiscrete for two); the rule heads are the loaded policy's rules, in batch; the partner is
    drawn per game from the recipe's partners (recipe_partner)."""

    render_mode = None

    def __init__(
        self, recipe: Recipe, n_envs: int, config: GameConfig | None = None, root: Path = LIBRARY
    ) -> None:
        self.recipe = recipe
        self.config = config or GameConfig()
        partners = [recipe_partner(name, recipe, self.config, root) for name in recipe.partners]
        weights, reward = dict(recipe.weights), REWARDS[recipe.reward]
        self.env = RoleVectorEnv(
            n_envs,
            recipe.role,
            partners,
            self.config,
            recipe.view,
            lambda b, s, p: reward(b, s, p, weights),
            end_on_death=True,
        )
        self.features = np.array(FEATURES[recipe.features])
        bound = self.env.single_observation_space.high[0]
        sizes = [HEAD_SIZES[h] for h in recipe.learned]
        super().__init__(
            n_envs,
            spaces.Box(-bound, bound, (len(self.features),), np.float32),
            spaces.Discrete(sizes[0]) if len(sizes) == 1 else spaces.MultiDiscrete(sizes),
        )
        self.obs = np.zeros((n_envs, self.env.single_observation_space.shape[0]), np.float32)
        self.actions = np.zeros(n_envs, np.int64)
        self.returns, self.lengths = np.zeros(n_envs), np.zeros(n_envs, np.int64)

    def reset(self) -> np.ndarray:
        self.obs, _ = self.env.reset(seed=self._seeds[0])
        self._reset_seeds()
        return self.obs[:, self.features]

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = np.asarray(actions).reshape(self.num_envs, -1)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        heads = dict(zip(self.recipe.learned, self.actions.T, strict=True))
        heads |= networks.rule_heads_batch(self.recipe, self.obs, self.config)
        action = join_action(*(heads[h] for h in HEADS))
        self.obs, rewards, terminated, truncated, infos = self.env.step(action)
        self.returns += rewards
        self.lengths += 1
        out: list[dict] = [{} for _ in range(self.num_envs)]
        for lane in np.flatnonzero(terminated | truncated):
            out[lane] = {
                "terminal_observation": infos["final_obs"][lane, self.features],
                "TimeLimit.truncated": bool(truncated[lane]),
                "episode": {"r": float(self.returns[lane]), "l": int(self.lengths[lane]), "t": 0.0},
            }
            self.returns[lane], self.lengths[lane] = 0.0, 0
        return self.obs[:, self.features], rewards.astype(np.float32), terminated | truncated, out

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: object = None) -> list:
        return [getattr(self, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: object, indices: object = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: object, indices: object = None, **kwargs: object) -> list:
        return [getattr(self, method_name)(*args, **kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: object = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))
