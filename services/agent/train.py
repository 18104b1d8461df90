"""Training the library's learned policies with Stable-Baselines3 (the `train` extra).

`train(key)` follows the policy's registry recipe: a Gymnasium env over the learned heads only
(the rule heads are filled in by the same rules the loaded policy uses), the recipe's reward, a
pool of partners from the other role's library, and the recipe's algorithm. The result is exported
to plain arrays (library.py plays it in numpy) and recorded in the manifest with its hash, steps,
seed, score and the command that made it.
"""

from __future__ import annotations

import fcntl
import json
import math
import random
import shlex
import sys
import time
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import gymnasium
import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure

from services.agent import library
from services.agent.library import FEATURES, HEAD_SIZES, HEADS, LIBRARY, Recipe
from services.agent.scripted import CircleBait, MirrorShooter
from services.sim.engine import Event, Game
from services.sim.env import RoleEnv
from services.sim.observation import observe
from services.sim.play import play, summarize
from shared.game import ROLES, GameConfig, Policy, bait_first, join_action

# --- rewards -------------------------------------------------------------------------------------


def _ship(game: Game, role: str):  # noqa: ANN202 - an engine Ship
    return game.ships[ROLES.index(role)]


def region_reward(game: Game, role: str, events: list[Event], weights: dict[str, float]) -> float:
    ship = _ship(game, role)
    return float(ship.alive and ship.in_region)


def border_bearing_death_reward(
    game: Game, role: str, events: list[Event], weights: dict[str, float]
) -> float:
    ship = _ship(game, role)
    reward = -weights["death"] * sum(e.kind == "death" and e.role == role for e in events)
    if ship.alive and ship.in_region:
        r = math.hypot(ship.x, ship.y) or 1.0
        h = math.radians(ship.heading)
        bearing = -(ship.x * math.cos(h) + ship.y * math.sin(h)) / r  # cos of the angle to the fortress
        reward += weights["border"] * r / game.config.region_radius + weights["bearing"] * bearing
    return reward


def shooter_position_reward(game: Game, role: str, events: list[Event], weights: dict[str, float]) -> float:
    c = game.config
    me, bait = _ship(game, role), game.ships[0]
    reward = weights["kill"] * sum(e.kind == "kill" for e in events)
    if not me.alive:
        return reward
    r = math.hypot(me.x, me.y)
    if not bait.in_region:
        return reward + float(c.region_radius < r < c.region_radius + 60.0)
    rear = math.radians(game.facing + 180.0)
    off = abs((math.atan2(me.y, me.x) - rear + math.pi) % (2 * math.pi) - math.pi)
    return reward + float(off < math.radians(40.0) and c.region_radius < r < c.region_radius + 100.0)


REWARDS: dict[str, Callable[[Game, str, list[Event], dict[str, float]], float]] = {
    "region": region_reward,
    "border-bearing-death": border_bearing_death_reward,
    "shooter-position": shooter_position_reward,
}

# --- the env a recipe trains in ------------------------------------------------------------------


class PartnerPool:
    """Plays one of several partner policies per game, drawn from the game's partner seed."""

    view = "world"

    def __init__(self, partners: list[Policy]) -> None:
        self.partners = partners
        self.key, self.role = "+".join(p.key for p in partners), partners[0].role
        self.current = partners[0]

    def reset(self, seed: int | None = None) -> None:
        self.current = random.Random(seed).choice(self.partners)
        self.current.reset(seed)
        self.view = self.current.view

    def act(self, obs: np.ndarray) -> int:
        return self.current.act(obs)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return self.current.probs(obs)


class RecipeEnv(gymnasium.Env):
    """The learned heads of one recipe as a Gymnasium env: the observation is the recipe's feature
    set, the action the learned heads (Discrete for one, MultiDiscrete for two)."""

    def __init__(self, recipe: Recipe, config: GameConfig | None = None) -> None:
        self.recipe = recipe
        self.config = config or GameConfig()
        partners = PartnerPool([library.load(k, self.config) for k in recipe.partners])
        weights = dict(recipe.weights)
        reward = REWARDS[recipe.reward]
        self.env = RoleEnv(
            recipe.role, partners, self.config, recipe.view, lambda g, r, e: reward(g, r, e, weights)
        )
        self.features = np.array(FEATURES[recipe.features])
        bound = self.env.observation_space.high[0]
        self.observation_space = spaces.Box(-bound, bound, (len(self.features),), np.float32)
        sizes = [HEAD_SIZES[h] for h in recipe.learned]
        self.action_space = spaces.Discrete(sizes[0]) if len(sizes) == 1 else spaces.MultiDiscrete(sizes)
        self.obs: np.ndarray | None = None

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.obs, info = self.env.reset(seed=int(self.np_random.integers(2**31 - 1)))
        return self.obs[self.features], info

    def step(self, action: np.ndarray | int) -> tuple[np.ndarray, float, bool, bool, dict]:
        heads = dict(zip(self.recipe.learned, np.atleast_1d(action).tolist(), strict=True))
        heads |= library.rule_heads(self.recipe, self.obs, self.config)
        turn, thrust, fire = (int(heads[h]) for h in HEADS)
        self.obs, reward, terminated, truncated, info = self.env.step(join_action(turn, thrust, fire))
        return self.obs[self.features], reward, terminated, truncated, info


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
    n_envs = N_ENVS[recipe.algorithm]
    env = make_vec_env(RecipeEnv, n_envs, seed, env_kwargs={"recipe": recipe, "config": config})
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
    only labels: DAgger's correction of the states a learner drifts into."""
    env = RecipeEnv(recipe)
    demonstrator = DEMONSTRATORS[recipe.role](**recipe.demonstrator)
    features, labels, returns = [], [], []
    for game in range(first_seed, first_seed + games):
        obs, _ = env.reset(seed=game)
        rewards, done = [], False
        while not done:
            heads = dict(zip(HEADS, demonstrator.choose(observe(env.env.game, recipe.role)), strict=True))
            label = [heads[h] for h in recipe.learned]
            features.append(obs)
            labels.append(label)
            action = label if learner is None else learner.predict(obs, deterministic=False)[0]
            obs, reward, _, done, _ = env.step(np.array(action))
            rewards.append(reward)
        g, game_returns = 0.0, []
        for reward in reversed(rewards):
            g = reward + gamma * g
            game_returns.append(g)
        returns += game_returns[::-1]
    return np.array(features), np.array(labels), np.array(returns, dtype=np.float32)


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
    """The policy network as plain arrays w0, b0, ... plus a JSON `meta` (activation, shapes)."""
    if recipe.algorithm == "DQN":
        layers, activation = model.policy.q_net.q_net, "relu"
    else:
        net = model.policy
        layers, activation = [*net.mlp_extractor.policy_net, net.action_net], "tanh"
    linear = [m for m in layers if isinstance(m, th.nn.Linear)]
    arrays = {}
    for i, m in enumerate(linear):
        arrays[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float32)
        arrays[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float32)
    meta = {"activation": activation, "key": recipe.key, "algorithm": recipe.algorithm}
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
        _record(out, key, entry)  # score() loads the policy through the manifest
        entry["score"] = score(key, recipe.partners[0], score_games, root=out)
    _record(out, key, entry)
    return entry


def _record(out: Path, key: str, entry: dict) -> None:
    """Write one manifest entry; a lock keeps parallel trainings from losing each other's."""
    with open(out / ".manifest.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = out / "manifest.json"
        entries = json.loads(path.read_text()) if path.exists() else {}
        entries[key] = entry
        path.write_text(json.dumps(entries, indent=2, sort_keys=True) + "\n")
