"""Building blocks of policies: factored distributions, rule-based and uniform play.

The `Policy` protocol itself is part of the game's vocabulary (shared/game.py).
"""

from __future__ import annotations

import math
import random

import numpy as np

from services.sim.jit import jitable
from shared.game import N_ACTIONS, N_FIRE, N_THRUST, N_TURN, join_action


def factored_probs(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """Joint distribution over the actions (shared.game.join_action) from three independent heads."""
    return (turn[:, None, None] * thrust[None, :, None] * fire[None, None, :]).reshape(N_ACTIONS)


def factored_probs_batch(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """factored_probs() of every row of the three heads' (rows, n) distributions, the same products."""
    return (turn[:, :, None, None] * thrust[:, None, :, None] * fire[:, None, None, :]).reshape(-1, N_ACTIONS)


def rule_head_probs(choices: np.ndarray, n: int, epsilon: float) -> np.ndarray:
    """(rows, n) distributions of a rule head: each row's choice with 1 - epsilon, the rest spread."""
    out = np.full((len(choices), n), epsilon / (n - 1))
    out[np.arange(len(choices)), choices] = 1.0 - epsilon
    return out


class RulePolicy:
    """A rule picks one choice per head; the policy plays it with probability 1 - epsilon per head
    and spreads epsilon evenly over that head's other choices (EPSILON, documented in the library
    docs), so every action keeps a small, known probability."""

    EPSILON = 0.01
    key = "rule"
    role = "bait"
    view = "world"

    def __init__(self, epsilon: float = EPSILON) -> None:
        if not 0.0 < epsilon < 1.0:
            raise ValueError(f"epsilon must be in (0, 1), got {epsilon}")
        self.epsilon = epsilon
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        """The rule: (turn, thrust, fire) intended for this observation."""
        raise NotImplementedError

    def act(self, obs: np.ndarray) -> int:
        turn, thrust, fire = self.choose(obs)
        rng, eps = self.rng, self.epsilon
        if rng.random() < eps:
            turn = (turn + rng.randrange(1, N_TURN)) % N_TURN
        if rng.random() < eps:
            thrust = 1 - thrust
        if rng.random() < eps:
            fire = 1 - fire
        return join_action(turn, thrust, fire)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        choices = zip(self.choose(obs), (N_TURN, N_THRUST, N_FIRE), strict=True)
        return factored_probs(*(rule_head_probs(np.array([c]), n, self.epsilon)[0] for c, n in choices))

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        """choose() of every row, (rows, 3); the project's rules run their compiled form."""
        return np.array([self.choose(obs) for obs in observations], np.int64).reshape(-1, 3)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        """probs() of every row of an (n, 64) array."""
        choices = self.choose_batch(observations)
        sizes = (N_TURN, N_THRUST, N_FIRE)
        return factored_probs_batch(
            *(rule_head_probs(choices[:, k], n, self.epsilon) for k, n in enumerate(sizes))
        )


class UniformPolicy:
    """Every action equally likely: the random baseline."""

    view = "world"

    def __init__(self, role: str, key: str = "random") -> None:
        self.role, self.key = role, key
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def act(self, obs: np.ndarray) -> int:
        return self.rng.randrange(N_ACTIONS)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return np.full(N_ACTIONS, 1.0 / N_ACTIONS)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        return np.full((len(observations), N_ACTIONS), 1.0 / N_ACTIONS)


@jitable
def turn_toward(heading_cos: float, heading_sin: float, angle: float, deadband: float = 3.0) -> int:
    """Turn choice (0 none, 1 left, 2 right) that brings the heading toward `angle` (radians)."""
    heading = math.atan2(heading_sin, heading_cos)
    error = math.degrees((angle - heading + math.pi) % (2 * math.pi) - math.pi)
    if error > deadband:
        return 1
    if error < -deadband:
        return 2
    return 0
