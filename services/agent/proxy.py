"""A proxy's files: a network cloned from recorded people, played like any other policy.

A proxy directory holds `proxy.npz` (the network's arrays and its metadata, read with
`allow_pickle=False`) and `manifest.json` (what it learned from, the split, the metrics, the
command, the weights' hash). The network reads the whole world-view observation and outputs the
logits of the three heads (turn, thrust, fire); it is played by networks.ProxyPolicy, whose `probs`
is exactly the distribution the training maximised the likelihood of.

It plays as `proxy:DIR` wherever a policy key or partner name is accepted (services/agent/outside.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.agent.library import file_hash
from services.agent.networks import Network, ProxyPolicy
from shared.errors import UsageError

PROXY = "proxy:"  # a proxy's key: proxy:DIR
WEIGHTS, MANIFEST = "proxy.npz", "manifest.json"


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
