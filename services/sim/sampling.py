"""How a batch turns policies' distributions into actions: every lane at once, reproducibly.

`batch_probs` asks a policy for all lanes' distributions in one call; `sample` draws one action
per lane from its row (`act_lanes`: lanes of several policies, each policy asked once);
`lane_uniforms` is the counter-based generator behind the draws, keyed by a game's seed, a stream
(the seat) and the frame, so that a batched game depends on its own seed only, never on which
lanes share its batch or which worker plays it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from services.sim.jit import compiled, jitable
from shared.game import Policy


def batch_probs(policy: Policy, observations: np.ndarray) -> np.ndarray:
    """The (n, 12) distributions of a policy over n observations, batched where the policy can
    (every policy of the project can; a plug-in without `probs_batch` is asked row by row)."""
    if hasattr(policy, "probs_batch"):
        return policy.probs_batch(observations)
    return np.stack([policy.probs(obs) for obs in observations])


def batch_act(policy: Policy, observations: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per observation, drawn from the policy's distribution with the given uniforms
    (not the policy's own per-game stream: a batch samples all its lanes at once)."""
    return sample(batch_probs(policy, observations), uniforms)


def act_lanes(
    policies: Sequence[Policy],
    choice: np.ndarray,
    observed: Callable[[str], np.ndarray],
    uniforms: np.ndarray,
) -> np.ndarray:
    """One action per lane: lane i's drawn from `policies[choice[i]]` with `uniforms[i]`, each
    policy asked once for all its lanes; `observed(view)`: every lane's observation in that view."""
    used = np.unique(choice)
    if len(used) == 1:  # one policy for every lane: no gathering
        policy = policies[used[0]]
        return batch_act(policy, observed(policy.view), uniforms)
    out = np.empty(len(choice), np.int64)
    for k in used:
        policy, lanes = policies[k], np.flatnonzero(choice == k)
        out[lanes] = batch_act(policy, observed(policy.view)[lanes], uniforms[lanes])
    return out


def sample(probs: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of (rows, 12) distributions: the first action whose cumulative
    probability exceeds the row's uniform draw (the last one should rounding leave none)."""
    out = np.empty(len(probs), np.int64)
    _sample(np.ascontiguousarray(probs, np.float64), np.asarray(uniforms, np.float64), out)
    return out


def lane_uniforms(seeds: np.ndarray, stream: int, frame: int | np.ndarray) -> np.ndarray:
    """One uniform in [0, 1) per game seed for (stream, frame): a counter-based generator, so a
    batched game's draws depend on its own seed only, never on which lanes share its batch or
    which worker plays it."""
    keys = np.asarray(seeds).astype(np.uint64)
    counters = np.asarray(frame).astype(np.uint64) + np.uint64(stream << 32)
    if counters.shape != keys.shape:
        counters = np.full(keys.shape, counters, np.uint64)
    out = np.empty(keys.shape, np.float64)
    _uniforms(keys, counters, out)
    return out


@compiled
def _sample(probs, uniforms, out):
    for i in range(probs.shape[0]):
        total, out[i] = 0.0, probs.shape[1] - 1
        for j in range(probs.shape[1]):
            total += probs[i, j]
            if uniforms[i] < total:
                out[i] = j
                break


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@jitable
def _mix(z):
    """SplitMix64's finaliser: a bijection of 64-bit words that scatters every input bit."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@compiled
def _uniforms(keys, counters, out):
    for i in range(keys.shape[0]):
        key = _mix(keys[i] * _GOLDEN + _GOLDEN)
        z = _mix(key ^ (counters[i] * _GOLDEN))
        out[i] = np.float64(z >> _S11) * 2.0**-53
