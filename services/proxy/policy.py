"""A proxy as a policy like any other: numpy inference over the exported network, exact `probs`.

A proxy directory holds `proxy.npz` (the network's arrays and its metadata, read with
`allow_pickle=False`) and `manifest.json` (what it learned from, the split, the metrics, the
command, the weights' hash). The network reads the whole world-view observation and outputs the
logits of the three heads (turn, thrust, fire); each head is a softmax with library.FLOOR mixed in,
and the action's probability is their product: the distribution the training maximised the
likelihood of, so `probs` is exactly what was learned and what `act` draws from.

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

WEIGHTS, MANIFEST = "proxy.npz", "manifest.json"
SPLITS = np.cumsum([HEAD_SIZES[h] for h in HEADS])[:-1]  # where each head's logits end


def head_probs(logits: np.ndarray) -> list[np.ndarray]:
    """Each head's distribution from the (rows, 7) logits: softmax with FLOOR mixed in."""
    out = []
    for part in np.split(logits, SPLITS, axis=-1):
        out.append((1.0 - FLOOR) * softmax(part) + FLOOR / part.shape[-1])
    return out


class ProxyPolicy:
    """A behaviour-cloned person (module docstring)."""

    def __init__(self, key: str, role: str, network: Network, view: str = "world") -> None:
        self.key, self.role, self.view, self.network = key, role, view, network
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        return factored_probs_batch(*head_probs(self.network(observations.astype(np.float64))))

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return self.probs_batch(obs[None])[0]

    def act(self, obs: np.ndarray) -> int:
        return draw(self.rng, self.probs(obs))


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
    return ProxyPolicy(key or f"{PROXY}{Path(directory).name}", role, network, meta["view"])
