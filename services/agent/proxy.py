"""A proxy as a policy like any other: numpy inference over the exported network, exact `probs`.

A proxy directory holds `proxy.npz` (the network's arrays and its metadata, read with
`allow_pickle=False`) and `manifest.json` (what it learned from, the split, the metrics, the
command, the weights' hash). The network reads the whole world-view observation and outputs the
logits of the three heads (turn, thrust, fire); each head is a softmax with library.FLOOR mixed in,
and the action's probability is their product: the distribution the training maximised the
likelihood of, so `probs` is exactly what was learned and what `act` draws from.

A proxy trained with history k (`tsf proxy train --history k`) also reads its own last k actions
(one-hot, latest first): a person holds keys down, so the last action says much about the next.
It remembers what it played since `reset`; `probs` is its distribution given that memory, and
`probs_given` the distribution given any actions before (what the training scored).

It plays as `proxy:DIR` wherever a policy key or partner name is accepted (services/agent/outside.py).
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np

from services.agent.library import FLOOR, HEAD_SIZES, HEADS, Network, draw, file_hash, softmax
from services.agent.outside import PROXY
from services.agent.policy import factored_probs_batch
from shared.errors import UsageError
from shared.game import N_ACTIONS

WEIGHTS, MANIFEST = "proxy.npz", "manifest.json"
SPLITS = np.cumsum([HEAD_SIZES[h] for h in HEADS])[:-1]  # where each head's logits end


def head_probs(logits: np.ndarray) -> list[np.ndarray]:
    """Each head's distribution from the (rows, 7) logits: softmax with FLOOR mixed in."""
    out = []
    for part in np.split(logits, SPLITS, axis=-1):
        out.append((1.0 - FLOOR) * softmax(part) + FLOOR / part.shape[-1])
    return out


def inputs(observations: np.ndarray, previous: np.ndarray, history: int) -> np.ndarray:
    """The network's input rows: the observation, then each of the last `history` actions one-hot."""
    rows = len(observations)
    previous = np.asarray(previous, np.int64).reshape(rows, -1)
    hot = np.zeros((rows, history, N_ACTIONS))
    hot[np.arange(rows)[:, None], np.arange(history)[None, :], previous[:, :history]] = 1.0
    return np.hstack([observations.astype(np.float64), hot.reshape(rows, -1)])


class ProxyPolicy:
    """A behaviour-cloned person (module docstring)."""

    def __init__(self, key: str, role: str, network: Network, view: str = "world", history: int = 0) -> None:
        self.key, self.role, self.view, self.network, self.history = key, role, view, network, history
        self.reset(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)
        self.played = np.zeros(self.history, np.int64)  # its last actions, latest first

    def probs_given(self, observations: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """(rows, 12) distributions given each row's actions before it ((rows, >= history), latest first)."""
        return factored_probs_batch(*head_probs(self.network(inputs(observations, previous, self.history))))

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        """Every row's distribution given what the proxy itself played last (its memory)."""
        return self.probs_given(observations, np.tile(self.played, (len(observations), 1)))

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return self.probs_batch(obs[None])[0]

    def act(self, obs: np.ndarray) -> int:
        action = draw(self.rng, self.probs(obs))
        if self.history:
            self.played = np.roll(self.played, 1)
            self.played[0] = action
        return action


def save(directory: Path, arrays: dict[str, np.ndarray], meta: dict, record: dict) -> dict:
    """Write a proxy: the arrays with `meta` as proxy.npz, and `record` with the weights' hash as the
    manifest. Returns the manifest."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    weights = directory / WEIGHTS
    np.savez(weights, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    record = {**record, "file": WEIGHTS, "sha256": file_hash(weights)}
    (directory / MANIFEST).write_text(json.dumps(record, indent=1) + "\n")
    return record


def manifest(directory: Path, option: str = "--policy") -> dict:
    """The proxy's manifest, refused (UsageError) where the directory holds no proxy or its weights
    do not match the manifest's hash."""
    directory = Path(directory)
    path = directory / MANIFEST
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise UsageError(option, directory, f"not a proxy directory ({MANIFEST}: {error})") from None
    weights = directory / WEIGHTS
    if not weights.is_file() or file_hash(weights) != record.get("sha256"):
        raise UsageError(option, directory, f"{WEIGHTS} is missing or does not match its manifest hash")
    return record


def load(directory: Path, role: str, key: str = "", option: str = "--policy") -> ProxyPolicy:
    """The proxy in `directory`, checked to play `role` (UsageError if not). `key`: its name in
    messages (default: proxy:<directory name>)."""
    record = manifest(directory, option)
    if record["role"] != role:
        raise UsageError(
            option, directory, f"is a proxy of the {record['role']} seat, not the {role}", [role]
        )
    network, meta = Network.load(Path(directory) / WEIGHTS)
    name = key or f"{PROXY}{Path(directory).name}"
    return ProxyPolicy(name, role, network, meta["view"], meta.get("history", 0))
