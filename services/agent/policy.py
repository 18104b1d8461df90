"""The policy interface every player of TSF implements: library, scripted, random or human proxy.

A policy is reset with a seed, reads the observation vector of its role (in the frame it names),
returns an action, and returns the full distribution over the 12 actions it samples from. The
distribution is what the adapter's cross-entropy metric reads, so it must be the real sampling
distribution and never zero anywhere.
"""

from __future__ import annotations

import math
import random
from typing import Protocol, runtime_checkable

import numpy as np

from services.sim.config import N_ACTIONS
from services.sim.jit import jitable

N_TURN, N_THRUST, N_FIRE = 3, 2, 2


@runtime_checkable
class Policy(Protocol):
    key: str
    role: str
    frame: str  # the observation frame it reads: "world" or "role"

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs: np.ndarray) -> int: ...

    def probs(self, obs: np.ndarray) -> np.ndarray: ...


def factored_probs(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """Joint distribution over action = turn * 4 + thrust * 2 + fire from three independent heads."""
    return (turn[:, None, None] * thrust[None, :, None] * fire[None, None, :]).reshape(N_ACTIONS)


def factored_probs_batch(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """factored_probs() of every row of the three heads' (rows, n) distributions, the same products."""
    return (turn[:, :, None, None] * thrust[:, None, :, None] * fire[:, None, None, :]).reshape(-1, N_ACTIONS)


def rule_head_probs(choices: np.ndarray, n: int, epsilon: float) -> np.ndarray:
    """(rows, n) distributions of a rule head: each row's choice with 1 - epsilon, the rest spread."""
    out = np.full((len(choices), n), epsilon / (n - 1))
    out[np.arange(len(choices)), choices] = 1.0 - epsilon
    return out


def sample(probs: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of (rows, 12) distributions: the first action whose cumulative
    probability exceeds the row's uniform draw (the last one should rounding leave none)."""
    below = np.cumsum(probs, axis=1) <= uniforms[:, None]
    return np.minimum(below.sum(axis=1), probs.shape[1] - 1)


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser: a bijection of 64-bit words that scatters every input bit."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def lane_uniforms(seeds: np.ndarray, stream: int, frame: int | np.ndarray) -> np.ndarray:
    """One uniform in [0, 1) per game seed for (stream, frame): a counter-based generator, so a
    batched game's draws depend on its own seed only, never on which lanes share its batch or
    which worker plays it."""
    counter = np.asarray(frame).astype(np.uint64) + np.uint64(stream << 32)
    with np.errstate(over="ignore"):
        key = _mix(np.asarray(seeds).astype(np.uint64) * _GOLDEN + _GOLDEN)
        z = _mix(key ^ counter * _GOLDEN)
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


class RulePolicy:
    """A rule picks one choice per head; the policy plays it with probability 1 - epsilon per head
    and spreads epsilon evenly over that head's other choices (EPSILON, documented in the library
    docs), so every action keeps a small, known probability."""

    EPSILON = 0.01
    key = "rule"
    role = "bait"
    frame = "world"

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
        return turn * 4 + thrust * 2 + fire

    def probs(self, obs: np.ndarray) -> np.ndarray:
        heads = []
        for choice, n in zip(self.choose(obs), (N_TURN, N_THRUST, N_FIRE), strict=True):
            head = np.full(n, self.epsilon / (n - 1))
            head[choice] = 1.0 - self.epsilon
            heads.append(head)
        return factored_probs(*heads)

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

    frame = "world"

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
