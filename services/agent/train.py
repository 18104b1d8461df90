"""Training the library's learned policies with Stable-Baselines3 (the `train` extra).

`train(key)` follows the policy's registry recipe: a vectorised env over the learned heads only
(lanes of the batched engine; the rule heads are filled in by the same rules the loaded policy
uses), the recipe's reward, a pool of partners from the other role's library, and the recipe's
algorithm. The result is exported
to plain arrays (library.py plays it in numpy) and recorded in the manifest with its hash, steps,
seed, score and the command that made it.
"""

from __future__ import annotations

import csv
import fcntl
import json
import math
import multiprocessing
import shlex
import shutil
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from services import envs
from services.adapter.human_like import HumanLike
from services.adapter.partners import HumanLanes, make_partner
from services.agent import library, networks
from services.agent.library import FEATURES, LIBRARY, Recipe
from services.agent.networks import HEAD_SIZES, HEADS
from services.agent.outside import KEY, check_view, linear_arrays, network_arrays, proxy_arrays
from services.agent.scripted import CircleBait, MirrorShooter, scripted_keys
from services.provenance import provenance
from services.sim.batch import BatchGame
from services.sim.batch_play import play_batch
from services.sim.observation import observe
from services.sim.play import summarize
from services.sim.vec_env import RoleVectorEnv
from shared.errors import UsageError
from shared.game import ROLES, GameConfig, Policy, bait_first, join_action, other

# --- rewards: one value per lane of a batched game, for the learner's seat -----------------------


def opening(batch: BatchGame, seat: int) -> np.ndarray:
    """Whether the fortress, up and locked on this bait, is firing with its open back to the
    shooter: the frames in which the bait's work can become a kill."""
    s, shooter = batch.state, 1 - seat
    rear = np.radians(s.facing + 180.0)
    bearing = np.arctan2(s.y[:, shooter], s.x[:, shooter])
    behind = np.abs((bearing - rear + np.pi) % (2 * np.pi) - np.pi) <= np.radians(batch.config.rear_arc / 2)
    both = s.alive[:, seat] & s.alive[:, shooter]
    return both & s.fortress_alive & (s.lock == seat) & (s.vulnerable > 0) & behind


def facing(batch: BatchGame, seat: int) -> np.ndarray:
    """The cosine of the angle between this ship's heading and its bearing to the fortress."""
    s = batch.state
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    h = np.radians(s.heading[:, seat])
    return -(x * np.cos(h) + y * np.sin(h)) / np.where(r == 0.0, 1.0, r)


def drawing_fire_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """1 per frame of `opening`, plus `kill` per team kill. The study paid 1 per frame in the
    region. From scratch that taught baits to stay in after a kill (which keeps the fortress from
    respawning) and to circle faster than the fortress turns or the shooter follows: region time
    without kills."""
    return opening(batch, seat) + weights.get("kill", 0.0) * batch.event_counts("kill")


def border_bearing_death_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """The shaped family: border * distance / region radius + bearing * cos(heading to the
    fortress) per frame of `opening`, - death per death of this ship, + kill per team kill. The
    study paid the shaped terms on every frame in the region; from scratch its baits then sat at the
    border facing the fortress and drew no useful fire."""
    s = batch.state
    r = np.hypot(s.x[:, seat], s.y[:, seat])
    shaped = weights["border"] * r / batch.config.region_radius + weights["bearing"] * facing(batch, seat)
    deaths = batch.event_counts("death", seat)
    kills = weights.get("kill", 0.0) * batch.event_counts("kill")
    return kills - weights["death"] * deaths + np.where(opening(batch, seat), shaped, 0.0)


def shooter_position_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """The study's: 1 per frame just outside the region while the bait is out, 1 per frame at the
    fortress's rear while it is in, `kill` per kill; plus `aim` * cos(aim error)^16 per frame the
    fortress is up. Without the aim term the DQN shooters learned neither to aim nor to move (the
    kills that pay for aiming come too rarely to a shooter that turns at random; docs/library.md)."""
    s, region = batch.state, batch.config.region_radius
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    rear = np.radians(s.facing + 180.0)
    off = np.abs((np.arctan2(y, x) - rear + np.pi) % (2 * np.pi) - np.pi)
    waiting = (region < r) & (r < region + 60.0)  # just outside the region while the bait is out
    at_rear = (off < np.radians(40.0)) & (region < r) & (r < region + 100.0)
    placed = np.where(s.in_region[:, 0], at_rear, waiting) & s.alive[:, seat]
    aimed = np.clip(facing(batch, seat), 0.0, 1.0) ** 16 * (s.fortress_alive & s.alive[:, seat])
    return weights["kill"] * batch.event_counts("kill") + placed + weights.get("aim", 0.0) * aimed


REWARDS: dict[str, Callable[[BatchGame, int, np.ndarray, dict[str, float]], np.ndarray]] = {
    "drawing-fire": drawing_fire_reward,
    "border-bearing-death": border_bearing_death_reward,
    "shooter-position": shooter_position_reward,
}

# --- the env a recipe trains in ------------------------------------------------------------------


def recipe_partner(name: str, recipe: Recipe, config: GameConfig, root: Path):  # noqa: ANN201
    """One of a recipe's partners by name: a library key plays as the library plays it; a
    calibrated human-like stand-in (`human(B5,skill=novice)`, adapter/partners.py) plays in its
    batched form (adapter/partners.py), stateful per lane. Anything else is a UsageError."""
    if name in library.registry(root):
        return networks.load(name, config, root)

    partner = make_partner(name, other(recipe.role))
    if not isinstance(partner, HumanLike):
        raise UsageError(f"{recipe.key}.partners", name, "a recipe's partner is a library key or human(...)")
    return HumanLanes(partner)


def curve_partner(recipe: Recipe, root: Path) -> Policy:
    """The partner of a recipe's curve and score: its first library partner."""
    keys = [name for name in recipe.partners if name in library.registry(root)]
    if not keys:
        raise UsageError(f"{recipe.key}.partners", ", ".join(recipe.partners), "name no library policy")
    return networks.load(keys[0], root=root)


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
):  # noqa: ANN201 - an SB3 model
    """The recipe's algorithm on its env, with the algorithm's settings (or `hyperparameters`)."""
    settings = dict(HYPERPARAMETERS[recipe.algorithm] if hyperparameters is None else hyperparameters)
    env = RecipeVecEnv(recipe, settings.pop("n_envs"), config, root)
    kwargs = {"policy_kwargs": {"net_arch": NET}, **settings}
    return ALGORITHMS[recipe.algorithm]("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)


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


# --- a training run: curve, checkpoints, manifest ------------------------------------------------

EVAL_SEEDS = range(10_000, 10_016)  # the curve's games: seeds that no table or test plays
CURVE = ("steps", "seconds", "kills_per_minute", "stderr", "mean_return")


def policy_of(model, recipe: Recipe, config: GameConfig | None = None) -> networks.LearnedPolicy:  # noqa: ANN001
    """The model as the library plays it: the exported arrays, in numpy."""
    arrays = export(model, recipe)
    meta = json.loads(bytes(arrays.pop("meta")).decode())
    return networks.LearnedPolicy(recipe, networks.Network(arrays, meta["activation"]), config)


def team_score(policy: Policy, partner: Policy, seeds: range, config: GameConfig | None = None) -> dict:
    """Kills/min of `policy` with `partner` over seeded games (lanes of one batch)."""
    s = summarize(play_batch(*bait_first(policy.role, policy, partner), list(seeds), config))
    return {"partner": partner.key, "games": s.games, "kills_per_minute": s.mean, "stderr": s.stderr}


class Run(BaseCallback):
    """Every `every` steps: the learning curve's next point (kills/min with the recipe's first
    partner on EVAL_SEEDS, mean training return) and a checkpoint that a later call resumes."""

    def __init__(self, run_dir: Path, recipe: Recipe, partner: Policy, every: int, state: dict) -> None:
        super().__init__()
        self.run_dir, self.recipe, self.partner = run_dir, recipe, partner
        self.every, self.state = every, state
        self.clock, self.before = time.monotonic(), state["seconds"]  # seconds of earlier sessions

    def _on_training_start(self) -> None:
        self.next_at = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_at:
            self.point()
            self.next_at += self.every
        return True

    def seconds(self) -> float:
        return self.before + time.monotonic() - self.clock

    def point(self) -> dict:
        """Score the policy, add the curve's row, keep the best policy so far, save a checkpoint."""
        score = team_score(policy_of(self.model, self.recipe), self.partner, EVAL_SEEDS)
        if score["kills_per_minute"] >= self.state.get("best", {}).get("kills_per_minute", -1.0):
            np.savez(self.run_dir / "best.npz", **export(self.model, self.recipe))
            self.state["best"] = {"steps": self.num_timesteps, "kills_per_minute": score["kills_per_minute"]}
        returns = [e["r"] for e in self.model.ep_info_buffer]
        row = {
            "steps": self.num_timesteps,
            "seconds": round(self.seconds(), 1),
            "kills_per_minute": round(score["kills_per_minute"], 3),
            "stderr": round(score["stderr"], 3),
            "mean_return": round(float(np.mean(returns)), 3) if returns else "",
        }
        curve = self.run_dir / "curve.csv"
        with open(curve, "a", newline="") as f:
            writer = csv.DictWriter(f, CURVE)
            if f.tell() == 0:
                writer.writeheader()
            writer.writerow(row)
        self.model.save(self.run_dir / "checkpoint.zip")
        if isinstance(self.model, DQN):
            self.model.save_replay_buffer(self.run_dir / "replay.pkl")
        self.state |= {"steps": self.num_timesteps, "seconds": row["seconds"]}
        (self.run_dir / "checkpoint.json").write_text(json.dumps(self.state, indent=2) + "\n")
        return row


def plot_curve(curve: Path, out: Path, key: str) -> None:
    """The learning curve as a PNG: kills/min with the training partner (± s.e.) and mean return."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(curve) as f:
        rows = list(csv.DictReader(f))
    steps = np.array([float(r["steps"]) for r in rows]) / 1e6
    kpm = np.array([float(r["kills_per_minute"]) for r in rows])
    se = np.array([float(r["stderr"]) for r in rows])
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(steps, kpm, color="C0", label="kills/min")
    ax.fill_between(steps, kpm - se, kpm + se, color="C0", alpha=0.25)
    ax.set(xlabel="environment steps (millions)", ylabel="kills/min with training partner", title=key)
    ax.set_ylim(bottom=0)
    returns = [(x, float(r["mean_return"])) for x, r in zip(steps, rows, strict=True) if r["mean_return"]]
    if returns:
        twin = ax.twinx()
        twin.plot(*zip(*returns, strict=True), color="C1", alpha=0.7, label="mean return")
        twin.set_ylabel("mean training return", color="C1")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def whole_rollouts(model: BaseAlgorithm, steps: int) -> int:
    """`steps` rounded up to what SB3 plays for them: it collects whole rollouts (n_envs lanes of
    n_steps each on-policy, one step of every lane for DQN), so `learn(4096)` with 64 lanes of 128
    steps plays 8,192. Asking for that number keeps the progress bar's total true."""
    rollout = model.n_envs * getattr(model, "n_steps", 1)
    return -(-steps // rollout) * rollout


def train(
    key: str,
    out: Path,
    steps: int | None = None,
    seed: int | None = None,
    run_dir: Path = Path("runs"),
    hyperparameters: dict | None = None,
    warm_start: bool = False,
    every: int = 250_000,
    progress: bool = True,
    score_games: int = 20,
    figures: Path | None = None,
) -> dict:
    """Train one library policy by its recipe into the library at `out`: its weights, manifest
    entry and learning curve (`run_dir`/KEY/curve.csv, .png, and `figures`/train_KEY.png). A run
    stopped part way resumes from its last checkpoint when called again with the same settings."""
    recipe = library.registry(out)[key]
    if recipe.algorithm is None:
        raise ValueError(f"{key} is rule-based ({recipe.family}); there is nothing to train")
    steps = recipe.steps if steps is None else steps
    seed = recipe.seed if seed is None else seed
    settings = {
        "seed": seed,
        "hyperparameters": hyperparameters or HYPERPARAMETERS[recipe.algorithm],
        "warm_start": warm_start,
        "recipe": library.recipe_hash(recipe),
    }
    run_dir = run_dir / key
    run_dir.mkdir(parents=True, exist_ok=True)
    th.manual_seed(seed)
    th.set_num_threads(1)  # small networks: more threads only contend with the env and other trainings
    model, state, agreement = _resume(run_dir, recipe, settings, out)
    if model is None:
        for stale in ("curve.csv", "checkpoint.zip", "replay.pkl"):
            (run_dir / stale).unlink(missing_ok=True)
        model = make_model(recipe, seed, settings["hyperparameters"], root=out)
        agreement = warm_start_fit(model, recipe) if warm_start else None
        state = settings | {"steps": 0, "seconds": 0.0, "agreement": agreement}
    partner = curve_partner(recipe, out)
    run = Run(run_dir, recipe, partner, every, state)
    if state["steps"] < steps:
        todo = whole_rollouts(model, steps - state["steps"])
        model.learn(todo, callback=run, progress_bar=progress, reset_num_timesteps=False)
        run.point()
    plot_curve(run_dir / "curve.csv", run_dir / "curve.png", key)
    if figures is not None:
        plot_curve(run_dir / "curve.csv", figures / f"train_{key}.png", key)
    path = out / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "best.npz", path)
    entry = {
        "file": str(path.relative_to(out)),
        "sha256": library.file_hash(path),
        "algorithm": recipe.algorithm,
        "steps": int(model.num_timesteps),
        "seed": seed,
        "command": shlex.join(["tsf", "train", key, "--steps", str(steps), "--seed", str(seed)]),
        "argv": sys.argv,
        "seconds": state["seconds"],
        "selected": state["best"],
        "hyperparameters": settings["hyperparameters"],
        "warm_start": {"demonstrator": recipe.demonstrator, "agreement": agreement} if warm_start else None,
        "versions": {p: version(p) for p in ("stable-baselines3", "sb3-contrib", "torch", "numpy")},
    }
    if score_games:  # on seeds the selection did not see
        chosen = networks.LearnedPolicy(recipe, networks.Network.load(path)[0])
        entry["score"] = team_score(chosen, partner, range(score_games))
    record_entry(out, key, entry)
    return entry


def prepare(out: Path, keys: list[str] = ()) -> None:
    """A library directory to train `keys` into: an empty one starts as a copy of the shipped
    library (`library.copy`), so that untouched policies stay playable; candidate recipes among
    `keys` join its registry (`library.adopt`)."""
    if not (out / "registry.toml").exists() and out.exists() and any(out.iterdir()):
        raise UsageError("--library", out, "is neither a library (no registry.toml) nor empty")
    library.copy(out)
    library.adopt(out, list(keys))


def train_library(keys: list[str], out: Path, jobs: int = 1, **options: object) -> dict[str, dict]:
    """Train `keys` into the library at `out`, `jobs` at a time: the baits first, then the shooters,
    which train with baits of this library. Returns each key's manifest entry."""
    prepare(out, keys)
    recipes = library.registry(out)
    entries: dict[str, dict] = {}
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        for role in ROLES:
            group = [k for k in keys if recipes[k].role == role]
            futures = {k: pool.submit(train, k, out, **options) for k in group}
            entries |= {k: f.result() for k, f in futures.items()}
    return entries


def _resume(run_dir: Path, recipe: Recipe, settings: dict, out: Path) -> tuple:
    """(model, state, agreement) from the run's checkpoint, or Nones when there is none to resume:
    no checkpoint, or one made with other settings (then the run starts over)."""
    checkpoint = run_dir / "checkpoint.json"
    if not checkpoint.exists():
        return None, None, None
    state = json.loads(checkpoint.read_text())
    if {k: state.get(k) for k in settings} != json.loads(json.dumps(settings)):
        return None, None, None
    hyperparameters = dict(settings["hyperparameters"])
    env = RecipeVecEnv(recipe, hyperparameters.pop("n_envs"), root=out)
    model = ALGORITHMS[recipe.algorithm].load(run_dir / "checkpoint.zip", env=env, device="cpu")
    if isinstance(model, DQN):
        model.load_replay_buffer(run_dir / "replay.pkl")
    return model, state, state.get("agreement")


def record_entry(out: Path, key: str, entry: dict) -> None:
    """Write one manifest entry; a lock keeps parallel trainings from losing each other's."""
    with open(out / ".manifest.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = out / "manifest.json"
        entries = json.loads(path.read_text()) if path.exists() else {}
        entries[key] = entry
        path.write_text(json.dumps(entries, indent=2, sort_keys=True) + "\n")


def add(
    key: str, model: Path, role: str, directory: Path, view: str = "world", partner: str = "", games: int = 10
) -> dict:
    """Export an SB3 model, or a proxy directory (services/proxy), into the library at `directory`
    (created if need be, never the shipped one): weights/KEY.npz, a registry entry and a manifest
    entry with hashes and provenance, scored with `partner` (default: envs.DEFAULT_PARTNER) over
    `games` games. Returns the manifest entry."""
    check_view(role, view)
    directory = Path(directory)
    if directory.resolve() == library.LIBRARY.resolve():
        raise UsageError("--library", directory, "is the shipped library; give a directory of your own")
    if not KEY.match(key):
        raise UsageError("KEY", key, "a key is a letter, then letters, digits, - and _")
    taken = [*library.registry(), *scripted_keys("bait"), *scripted_keys("shooter")]
    if (directory / "registry.toml").exists():
        taken += list(library.registry(directory))
    if key in taken:
        raise UsageError("KEY", key, "is a policy key already")
    source = Path(model)
    if source.is_dir():  # a proxy (services/proxy): its network as it is, its own view
        arrays, family, view = proxy_arrays(source, key, role)
        source = source / "proxy.npz"
    else:
        arrays, family = (
            network_arrays(Path(model), {"key": key, "role": role, "view": view}),
            library.OUTSIDE,
        )
    meta = json.loads(bytes(arrays["meta"]).decode())
    path = directory / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    description = f"{meta['policy_class']} from {Path(model).name}"
    fields = {
        "role": role,
        "family": family,
        "view": view,
        "features": "all",
        "description": description,
    }
    with open(directory / "registry.toml", "a") as f:  # JSON strings are TOML basic strings
        f.write(f"\n[{key}]\n" + "".join(f"{name} = {json.dumps(value)}\n" for name, value in fields.items()))
    library._registry.cache_clear()
    entry = {
        "file": str(path.relative_to(directory)),
        "sha256": library.file_hash(path),
        "algorithm": meta["policy_class"],
        "source": {"file": str(Path(model).resolve()), "sha256": library.file_hash(source)},
        "provenance": provenance(**library.provenance_hashes()),
    }
    record_entry(directory, key, entry)
    if games:
        mate = networks.load(partner or envs.DEFAULT_PARTNER[role])
        entry["score"] = team_score(networks.load(key, root=directory), mate, range(games))
        record_entry(directory, key, entry)
    return entry
