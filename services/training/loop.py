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
import json
import multiprocessing
import shlex
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from services.agent import library, networks
from services.agent.library import Recipe, record_entry
from services.sim.batch_play import team_score
from services.training.algorithms import ALGORITHMS, HYPERPARAMETERS, export, make_model, warm_start_fit
from services.training.env import RecipeVecEnv, curve_partner
from shared.errors import UsageError
from shared.game import ROLES, GameConfig, Policy
from shared.processes import end_with_parent

EVAL_SEEDS = range(10_000, 10_016)  # the curve's games: seeds that no table or test plays
CURVE = ("steps", "seconds", "kills_per_minute", "stderr", "mean_return")


def policy_of(model, recipe: Recipe, config: GameConfig | None = None) -> networks.LearnedPolicy:  # noqa: ANN001
    """The model as the library plays it: the exported arrays, in numpy."""
    arrays = export(model, recipe)
    meta = json.loads(bytes(arrays.pop("meta")).decode())
    return networks.LearnedPolicy(recipe, networks.Network(arrays, meta["activation"]), config)


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
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(jobs, mp_context=spawn, initializer=end_with_parent) as pool:  # none outlives us
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
