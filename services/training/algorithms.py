"""The algorithms a recipe trains with (SB3's A2C, PPO, TRPO and a double-Q DQN), their settings,
the warm start by imitation of a scripted demonstrator, and the export to the library's plain arrays."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch as th
from sb3_contrib import TRPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.vec_env import VecEnv

from services.agent.library import LIBRARY, Recipe
from services.agent.networks import HEADS
from services.agent.outside import linear_arrays
from services.agent.scripted import DEMONSTRATOR, SCRIPTED
from services.sim.observation import observe
from services.training.env import RecipeVecEnv
from shared.game import GameConfig


class _DoubleTarget(th.nn.Module):
    """Stands in for DQN's target network in its TD target: the online network picks the next
    action, the target network values it (the target keeps -inf elsewhere so that DQN's max picks
    that value)."""

    def __init__(self, online: th.nn.Module, target: th.nn.Module) -> None:
        super().__init__()
        self.online, self.target = [online], target  # online in a list: not a second registration

    def forward(self, obs: th.Tensor) -> th.Tensor:
        best = self.online[0](obs).argmax(dim=1, keepdim=True)
        values = self.target(obs)
        return th.full_like(values, -math.inf).scatter(1, best, values.gather(1, best))


class DoubleDQN(DQN):
    """DQN with double-Q targets (van Hasselt et al. 2016)."""

    def _create_aliases(self) -> None:
        super()._create_aliases()
        self.q_net_target = _DoubleTarget(self.q_net, self.policy.q_net_target)


ALGORITHMS = {"A2C": A2C, "PPO": PPO, "TRPO": TRPO, "DQN": DoubleDQN}
NET = [64, 64]
# Per-algorithm settings (n_envs: lanes of the batched engine), one set for every recipe of the
# algorithm, chosen by the small search in docs/library.md and recorded in each manifest entry.
HYPERPARAMETERS: dict[str, dict] = {
    "A2C": {"n_envs": 64, "n_steps": 8, "learning_rate": 7e-4, "ent_coef": 0.01, "gamma": 0.99},
    "PPO": {
        "n_envs": 64,
        "n_steps": 128,
        "batch_size": 2048,
        "n_epochs": 4,
        "learning_rate": 3e-4,
        "ent_coef": 0.01,
        "gamma": 0.99,
    },
    "TRPO": {
        "n_envs": 64,
        "n_steps": 32,
        "batch_size": 512,
        "learning_rate": 1e-3,
        "gamma": 0.99,
        "target_kl": 0.03,
    },
    "DQN": {
        "n_envs": 64,
        "learning_starts": 20_000,
        "buffer_size": 300_000,
        "train_freq": 1,
        "gradient_steps": 4,
        "target_update_interval": 5_000,
        "exploration_fraction": 0.2,
        "exploration_final_eps": 0.05,
        "learning_rate": 1e-4,
        "batch_size": 256,
        "gamma": 0.99,
    },
}


def make_model(
    recipe: Recipe,
    seed: int,
    hyperparameters: dict | None = None,
    config: GameConfig | None = None,
    root: Path = LIBRARY,
    wrap: Callable[[VecEnv], VecEnv] | None = None,
):  # noqa: ANN201 - an SB3 model
    """The recipe's algorithm on its env (as `wrap` makes it, given), with the algorithm's settings
    (or `hyperparameters`)."""
    settings = dict(HYPERPARAMETERS[recipe.algorithm] if hyperparameters is None else hyperparameters)
    env = RecipeVecEnv(recipe, settings.pop("n_envs"), config, root)
    env = env if wrap is None else wrap(env)
    kwargs = {"policy_kwargs": {"net_arch": NET}, **settings}
    return ALGORITHMS[recipe.algorithm]("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)


def demonstrations(recipe: Recipe, games: int, gamma: float, learner=None, first_seed: int = 0):  # noqa: ANN001, ANN201
    """(features, head choices, discounted returns) of games in the recipe's env, labelled by the
    recipe's demonstrator (the scripted policy of its role with its `demonstrator` settings). It
    drives, or, given an SB3 `learner`, the learner does (its own samples) while the demonstrator
    only labels: DAgger's correction of the states a learner drifts into. The games are the lanes
    of one batch, seeded from `first_seed`."""
    env = RecipeVecEnv(recipe, games)
    env.seed(first_seed)
    demonstrator = SCRIPTED[DEMONSTRATOR[recipe.role]](**recipe.demonstrator)
    learned = [HEADS.index(h) for h in recipe.learned]
    obs = env.reset()
    features, labels, rewards = [], [], []
    for _ in range(env.config.frames):
        label = demonstrator.choose_batch(observe(env.env.batch, recipe.role))[:, learned]
        features.append(obs)
        labels.append(label)
        action = label if learner is None else learner.predict(obs, deterministic=False)[0]
        obs, reward, _, _ = env.step(action)
        rewards.append(reward)
    returns, g = np.empty((len(rewards), games), np.float32), np.zeros(games)
    for t in reversed(range(len(rewards))):
        g = rewards[t] + gamma * g
        returns[t] = g
    return np.concatenate(features), np.concatenate(labels), returns.reshape(-1)


def warm_start_fit(model, recipe: Recipe, rounds: int = 3, games: int = 4, epochs: int = 40) -> float:  # noqa: ANN001
    """Imitation before reinforcement learning: DAgger rounds fit the policy to the demonstrator's
    choices (and the value to the returns), so that training starts from a bait that holds the
    region rather than from a random walk; from scratch, 400k steps did not get there on two
    cores. Returns the fraction of the demonstrator's choices the fitted policy makes most likely."""
    policy = model.policy
    optimizer = th.optim.Adam(policy.parameters(), lr=1e-3)
    generator = th.Generator().manual_seed(0)
    data = [demonstrations(recipe, games, model.gamma)]
    for round_ in range(rounds):
        if round_:
            data.append(demonstrations(recipe, games, model.gamma, model, first_seed=round_ * games))
        obs, labels, returns = (np.concatenate(parts) for parts in zip(*data, strict=True))
        x, g = th.as_tensor(obs), th.as_tensor(returns)
        a = th.as_tensor(labels[:, 0] if labels.shape[1] == 1 else labels)
        for _ in range(epochs):
            for batch in th.randperm(len(x), generator=generator).split(256):
                loss = imitation_loss(model, x[batch], a[batch], g[batch])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
    with th.no_grad():
        if isinstance(model, DQN):
            model.policy.q_net_target.load_state_dict(model.policy.q_net.state_dict())
            mode = model.q_net(x).argmax(dim=1)
        else:
            mode = policy.get_distribution(x).mode()
    return float((mode.reshape(len(x), -1) == a.reshape(len(x), -1)).all(dim=1).float().mean())


def imitation_loss(model, x: th.Tensor, a: th.Tensor, g: th.Tensor) -> th.Tensor:  # noqa: ANN001
    """Negative log-likelihood of the demonstrator's choices plus the value's error on its
    returns; for DQN the Q values serve as the logits (so that greedy play imitates)."""
    if isinstance(model, DQN):
        q = model.q_net(x)
        return th.nn.functional.cross_entropy(q, a)
    values, log_prob, _ = model.policy.evaluate_actions(x, a)
    return -log_prob.mean() + 0.5 * ((values.flatten() - g) / 100.0).pow(2).mean()


def export(model, recipe: Recipe) -> dict[str, np.ndarray]:  # noqa: ANN001 - an SB3 model
    """The policy network as plain arrays (linear_arrays) with the recipe's key and algorithm."""
    if recipe.algorithm == "DQN":
        layers, activation = model.policy.q_net.q_net, "relu"
    else:
        net = model.policy
        layers, activation = [*net.mlp_extractor.policy_net, net.action_net], "tanh"
    return linear_arrays(layers, {"activation": activation, "key": recipe.key, "algorithm": recipe.algorithm})
