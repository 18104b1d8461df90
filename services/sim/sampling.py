"""How a batch turns policies' distributions into actions: every lane at once, reproducibly.

`batch_probs` asks a policy for all lanes' distributions in one call; `sample` draws one action
per lane from its row; `lane_uniforms` is the counter-based generator behind the draws, keyed by
a game's seed, a stream (the seat) and the frame, so that a batched game depends on its own seed
only, never on which lanes share its batch or which worker plays it.
"""

from __future__ import annotations

import numpy as np

from shared.game import Policy


def batch_probs(policy: Policy, observations: np.ndarray) -> np.ndarray:
    """The (n, 12) distributions of a policy over n observations, batched where the policy can
    (every policy of the project can; a plug-in without `probs_batch` is asked row by row)."""
    if hasattr(policy, "probs_batch"):
        return policy.probs_batch(observations)
    return np.stack([policy.probs(obs) for obs in observations])


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
