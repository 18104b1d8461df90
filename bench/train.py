"""Training throughput on the vectorised env: environment steps per second of Stable-Baselines3
PPO and double-Q DQN, wall clock including the updates (needs the `train` extra).

Each run is one process with one torch thread over `--lanes` games of the batched engine; the
2-core figure runs two such trainings at once (as `tsf train` runs policies side by side) and
adds their steps. Goals on 2 cores: PPO >= 30,000 steps/s, DQN >= 10,000 steps/s; PPO with the
calibrated human-like stand-ins as partners (how `tsf library grow` trains its best responses:
a group's members and their stand-ins) >= 60,000 steps/s. TRPO with the stand-ins, at the library's
TRPO settings (B6's recipe; issue 57 asks for the partners and best
responses to be trained with it): printed, no goal (`--lanes 64` is the recipes' own lane count).

    .venv/bin/python bench/train.py [--lanes 256] [--steps 200000] [--only 'PPO with stand-ins']
    .venv/bin/python bench/train.py --lanes 64 --only 'TRPO with stand-ins'
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

# Throughput settings: large rollouts over many lanes; the recipes' own settings are in train.py.
PPO = {"n_steps": 64, "batch_size": 2048, "n_epochs": 2, "learning_rate": 3e-5}
STAND_INS = ("human(S4,skill=novice)", "human(S5)", "human(S7,skill=practised)", "S4")
# (key, its settings (None: the library's for its algorithm), its partners: () for the recipe's own)
SETTINGS = {
    "PPO": ("B5", PPO, ()),
    "DQN": ("S1", {"learning_starts": 1000, "train_freq": 1, "gradient_steps": 1, "batch_size": 256}, ()),
    "PPO with stand-ins": ("B7", PPO, STAND_INS),
    "TRPO with stand-ins": ("B6", None, STAND_INS),
}


def steps_per_second(algorithm: str, lanes: int, steps: int) -> float:
    from dataclasses import replace

    import torch as th

    from services.agent import library
    from services.training.algorithms import ALGORITHMS, HYPERPARAMETERS, NET
    from services.training.env import RecipeVecEnv

    th.set_num_threads(1)
    key, settings, partners = SETTINGS[algorithm]
    recipe = library.registry()[key]
    if settings is None:  # the library's, but for the lanes: the bench's own
        settings = {k: v for k, v in HYPERPARAMETERS[recipe.algorithm].items() if k != "n_envs"}
    env = RecipeVecEnv(replace(recipe, partners=partners or recipe.partners), lanes)
    model = ALGORITHMS[recipe.algorithm](
        "MlpPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": NET}, **settings
    )
    model.learn(5 * lanes)  # warm: compiled loops, first rollout
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=256)
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--only", choices=list(SETTINGS), help="One setting only.")
    args = parser.parse_args()
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    for algorithm in [args.only] if args.only else SETTINGS:
        one = steps_per_second(algorithm, args.lanes, args.steps)
        with ProcessPoolExecutor(2) as pool:
            two = sum(pool.map(steps_per_second, [algorithm] * 2, [args.lanes] * 2, [args.steps] * 2))
        print(f"{algorithm} on {args.lanes} lanes: {one:,.0f} env steps/s on one core, {two:,.0f} on 2 cores")


if __name__ == "__main__":
    main()
