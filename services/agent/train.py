"""Training the library's learned policies with Stable-Baselines3 (the `train` extra).

`train(key)` follows the policy's registry recipe: a vectorised env over the learned heads only
(lanes of the batched engine; the rule heads are filled in by the same rules the loaded policy
uses), the recipe's reward, a pool of partners from the other role's library, and the recipe's
algorithm. The result is exported
to plain arrays (library.py plays it in numpy) and recorded in the manifest with its hash, steps,
seed, score and the command that made it.
"""

from __future__ import annotations

import fcntl
import json
import math
import shlex
import sys
import time
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecEnv

from services.agent import library
from services.agent.library import FEATURES, HEAD_SIZES, HEADS, LIBRARY, Recipe
from services.agent.scripted import CircleBait, MirrorShooter
from services.sim.batch import BatchGame
from services.sim.batch_observation import observe
from services.sim.play import play, summarize
from services.sim.vec_env import RoleVectorEnv
from shared.game import GameConfig, bait_first, join_action

# --- rewards: one value per lane of a batched game, for the learner's seat -----------------------


def region_reward(batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]) -> np.ndarray:
    s = batch.state
    return (s.alive[:, seat] & s.in_region[:, seat]).astype(np.float64)


def border_bearing_death_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    s = batch.state
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    r = np.where(r == 0.0, 1.0, r)
    h = np.radians(s.heading[:, seat])
    bearing = -(x * np.cos(h) + y * np.sin(h)) / r  # cos of the angle to the fortress
    inside = weights["border"] * r / batch.config.region_radius + weights["bearing"] * bearing
    deaths = batch.event_counts("death", seat)
    return -weights["death"] * deaths + np.where(s.alive[:, seat] & s.in_region[:, seat], inside, 0.0)


def shooter_position_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    s, region = batch.state, batch.config.region_radius
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    rear = np.radians(s.facing + 180.0)
    off = np.abs((np.arctan2(y, x) - rear + np.pi) % (2 * np.pi) - np.pi)
    waiting = (region < r) & (r < region + 60.0)  # just outside the region while the bait is out
    at_rear = (off < np.radians(40.0)) & (region < r) & (r < region + 100.0)
    placed = np.where(s.in_region[:, 0], at_rear, waiting) & s.alive[:, seat]
    return weights["kill"] * batch.event_counts("kill") + placed


REWARDS: dict[str, Callable[[BatchGame, int, np.ndarray, dict[str, float]], np.ndarray]] = {
    "region": region_reward,
    "border-bearing-death": border_bearing_death_reward,
    "shooter-position": shooter_position_reward,
}

# --- the env a recipe trains in ------------------------------------------------------------------


class RecipeVecEnv(VecEnv):
    """The learned heads of one recipe over lanes of the batched engine, as SB3's vectorised env:
    the observation is the recipe's feature set, the action the learned heads (Discrete for one,
    MultiDiscrete for two); the rule heads are the loaded policy's rules, in batch; the partner is
    drawn per game from the recipe's partners."""

    render_mode = None

    def __init__(self, recipe: Recipe, n_envs: int, config: GameConfig | None = None) -> None:
        self.recipe = recipe
        self.config = config or GameConfig()
        partners = [library.load(k, self.config) for k in recipe.partners]
        weights, reward = dict(recipe.weights), REWARDS[recipe.reward]
        self.env = RoleVectorEnv(
            n_envs, recipe.role, partners, self.config, recipe.view, lambda b, s, p: reward(b, s, p, weights)
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

    def reset(self) -> np.ndarray:
        self.obs, _ = self.env.reset(seed=self._seeds[0])
        self._reset_seeds()
        return self.obs[:, self.features]

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = np.asarray(actions).reshape(self.num_envs, -1)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        heads = dict(zip(self.recipe.learned, self.actions.T, strict=True))
        heads |= library.rule_heads_batch(self.recipe, self.obs, self.config)
        action = join_action(*(heads[h] for h in HEADS))
        self.obs, rewards, _, truncated, infos = self.env.step(action)
        out: list[dict] = [{} for _ in range(self.num_envs)]
        for lane in np.flatnonzero(truncated):
            out[lane] = {
                "terminal_observation": infos["final_obs"][lane, self.features],
                "TimeLimit.truncated": True,
            }
        return self.obs[:, self.features], rewards.astype(np.float32), truncated, out

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


# --- algorithms ----------------------------------------------------------------------------------


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
# Per-algorithm settings, chosen once for every recipe (recorded in each manifest entry).
HYPERPARAMETERS: dict[str, dict] = {
    "A2C": {"n_steps": 16, "learning_rate": 5e-5, "gamma": 0.99},
    "PPO": {"n_steps": 256, "batch_size": 512, "n_epochs": 5, "learning_rate": 3e-5},
    "TRPO": {"n_steps": 256, "batch_size": 512, "learning_rate": 1e-3, "gamma": 0.99},
    "DQN": {
        "learning_starts": 2000,
        "buffer_size": 100_000,
        "train_freq": 4,
        "target_update_interval": 2000,
        "exploration_initial_eps": 0.05,
        "exploration_final_eps": 0.02,
        "learning_rate": 1e-5,
        "batch_size": 64,
    },
}
N_ENVS = {"A2C": 16, "PPO": 16, "TRPO": 16, "DQN": 4}


def make_model(recipe: Recipe, seed: int, log_dir: Path | None, config: GameConfig | None = None):  # noqa: ANN201
    """The recipe's algorithm on its env, with the algorithm's settings above."""
    env = RecipeVecEnv(recipe, N_ENVS[recipe.algorithm], config)
    kwargs = {"policy_kwargs": {"net_arch": NET}, **HYPERPARAMETERS[recipe.algorithm]}
    model = ALGORITHMS[recipe.algorithm]("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)
    if log_dir is not None:
        model.set_logger(configure(str(log_dir), ["csv", "log"]))
    return model


DEMONSTRATORS = {"bait": CircleBait, "shooter": MirrorShooter}


def demonstrations(recipe: Recipe, games: int, gamma: float, learner=None, first_seed: int = 0):  # noqa: ANN001, ANN201
    """(features, head choices, discounted returns) of games in the recipe's env, labelled by the
    recipe's demonstrator (the scripted policy of its role with its `demonstrator` settings). It
    drives, or, given an SB3 `learner`, the learner does (its own samples) while the demonstrator
    only labels: DAgger's correction of the states a learner drifts into. The games are the lanes
    of one batch, seeded from `first_seed`."""
    env = RecipeVecEnv(recipe, games)
    env.seed(first_seed)
    demonstrator = DEMONSTRATORS[recipe.role](**recipe.demonstrator)
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


def warm_start(model, recipe: Recipe, rounds: int = 3, games: int = 4, epochs: int = 40) -> float:  # noqa: ANN001
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


def linear_arrays(layers: list[th.nn.Module], meta: dict) -> dict[str, np.ndarray]:
    """The linear layers among `layers` as arrays w0, b0, ... plus `meta` as JSON (library.Network)."""
    linear = [m for m in layers if isinstance(m, th.nn.Linear)]
    arrays = {}
    for i, m in enumerate(linear):
        arrays[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float32)
        arrays[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float32)
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return arrays


def score(key: str, partner: str, games: int, config: GameConfig | None = None, root: Path = LIBRARY) -> dict:
    """Kills/min of a library policy with a partner (from the shipped library) over seeded games."""
    policy = library.load(key, config, root)
    other = library.load(partner, config)
    pair = bait_first(policy.role, policy, other)
    s = summarize([play(*pair, seed, config) for seed in range(games)])
    return {"partner": partner, "games": s.games, "kills_per_minute": s.mean, "stderr": s.stderr}


def train(
    key: str,
    steps: int | None = None,
    seed: int | None = None,
    log_dir: Path | None = None,
    out: Path = LIBRARY,
    progress: bool = True,
    score_games: int = 10,
) -> dict:
    """Train one library policy by its recipe, write its weights and manifest entry, return it."""
    recipe = library.registry(out)[key]
    if recipe.algorithm is None:
        raise ValueError(f"{key} is rule-based ({recipe.family}); there is nothing to train")
    steps = recipe.steps if steps is None else steps
    seed = recipe.seed if seed is None else seed
    th.manual_seed(seed)
    th.set_num_threads(1)  # small networks: more threads only contend with the env and other trainings
    started = time.monotonic()
    model = make_model(recipe, seed, log_dir)
    agreement = warm_start(model, recipe) if recipe.demonstrator else None
    model.learn(total_timesteps=steps, progress_bar=progress)
    path = out / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **export(model, recipe))
    entry = {
        "file": str(path.relative_to(out)),
        "sha256": library.file_hash(path),
        "algorithm": recipe.algorithm,
        "steps": steps,
        "seed": seed,
        "command": shlex.join(["tsf", "train", key, "--steps", str(steps), "--seed", str(seed)]),
        "argv": sys.argv,
        "seconds": round(time.monotonic() - started, 1),
        "hyperparameters": HYPERPARAMETERS[recipe.algorithm],
        "warm_start": {"demonstrator": recipe.demonstrator, "agreement": agreement} if agreement else None,
        "versions": {p: version(p) for p in ("stable-baselines3", "sb3-contrib", "torch", "numpy")},
    }
    if score_games:
        record_entry(out, key, entry)  # score() loads the policy through the manifest
        entry["score"] = score(key, recipe.partners[0], score_games, root=out)
    record_entry(out, key, entry)
    return entry


def record_entry(out: Path, key: str, entry: dict) -> None:
    """Write one manifest entry; a lock keeps parallel trainings from losing each other's."""
    with open(out / ".manifest.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = out / "manifest.json"
        entries = json.loads(path.read_text()) if path.exists() else {}
        entries[key] = entry
        path.write_text(json.dumps(entries, indent=2, sort_keys=True) + "\n")
