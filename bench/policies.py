"""Library inference cost: what one frame of the adapter spends on action probabilities.

(a) one policy, one observation (probs); (b) all policies of a role, one observation; (c) all
policies of a role, a batch of 64 observations (per observation). Observations come from a
seeded game of the scripted pair; each policy reads them in its own view.

    .venv/bin/python bench/policies.py [--repeat N]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from services.agent import library, networks
from services.agent.scripted import CircleBait, MirrorShooter
from services.sim.observation import as_observation, world_values
from services.sim.play import play
from services.sim.sampling import batch_probs
from shared.game import ROLES


def sample_states(n: int = 64) -> dict[str, list[list[float]]]:
    """World-frame values of each role at n frames spread over a game."""
    states: dict[str, list[list[float]]] = {role: [] for role in ROLES}

    def trace(game, bait_action, shooter_action) -> None:  # noqa: ANN001
        if game.frame % 25 == 0 and len(states["bait"]) < n:
            for role in ROLES:
                states[role].append(world_values(game, role))

    play(CircleBait(), MirrorShooter(), seed=0, trace=trace)
    return states


def per_call(fn, repeat: int) -> float:  # noqa: ANN001
    """Best-of-5 mean seconds of fn() over `repeat` calls."""
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - start) / repeat)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=200)
    args = parser.parse_args()
    states = sample_states()
    for role in ROLES:
        report(role, states[role], args.repeat)


def report(role: str, states: list[list[float]], repeat: int) -> None:
    policies = [networks.load(k) for k in library.keys(role)]
    obs = {p.key: as_observation(states[0], p.view) for p in policies}
    batches = {p.key: np.stack([as_observation(s, p.view) for s in states]) for p in policies}
    print(f"{role}s ({len(policies)} policies)")
    for p in policies:
        t = per_call(lambda p=p: p.probs(obs[p.key]), repeat)
        print(f"  (a) {p.key:3s} one observation: {t * 1e6:7.1f} us")
    t_all = per_call(lambda: [p.probs(obs[p.key]) for p in policies], repeat)
    print(f"  (b) all {len(policies)}, one observation: {t_all * 1e6:7.1f} us")
    t_batch = per_call(lambda: [batch_probs(p, batches[p.key]) for p in policies], max(repeat // 20, 5))
    n = len(states)
    per_obs = t_batch / n * 1e6
    print(f"  (c) all {len(policies)}, batch of {n}: {t_batch * 1e3:.2f} ms = {per_obs:.1f} us each")


if __name__ == "__main__":
    main()
