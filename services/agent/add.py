"""`tsf library add`: a policy from outside (an SB3 model, a proxy directory) exported into a library
of yours, with its registry and manifest entries, and scored with a partner in bulk games. A module
of its own: it plays bulk games (numba), which no live agent that reads an outside policy loads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.agent import library, networks
from services.agent.outside import KEY, check_view, network_arrays, proxy_arrays
from services.agent.scripted import scripted_keys
from services.sim.batch_play import team_score
from shared.errors import UsageError
from shared.provenance import provenance


def add(
    key: str, model: Path, role: str, directory: Path, view: str = "world", partner: str = "", games: int = 10
) -> dict:
    """Export an SB3 model, or a proxy directory (services/proxy), into the library at `directory`
    (created if need be, never the shipped one): weights/KEY.npz, a registry entry and a manifest
    entry with hashes and provenance, scored with `partner` (default: library.DEFAULT_PARTNER) over
    `games` games. Returns the manifest entry."""
    check_view(role, view)
    directory = Path(directory)
    if directory.resolve() == library.LIBRARY.resolve():
        raise UsageError("--library", directory, "is the shipped library; give a directory of your own")
    if not KEY.match(key):
        raise UsageError("KEY", key, "a key is a letter, then letters, digits, - and _")
    taken = [*library.registry(), *scripted_keys("bait"), *scripted_keys("shooter")]
    if (directory / "registry.toml").exists():
        taken += list(library.registry(directory))
    if key in taken:
        raise UsageError("KEY", key, "is a policy key already")
    source = Path(model)
    if source.is_dir():  # a proxy (services/proxy): its network as it is, its own view
        arrays, family, view = proxy_arrays(source, key, role)
        source = source / "proxy.npz"
    else:
        arrays, family = (
            network_arrays(Path(model), {"key": key, "role": role, "view": view}),
            library.OUTSIDE,
        )
    meta = json.loads(bytes(arrays["meta"]).decode())
    path = directory / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    description = f"{meta['policy_class']} from {Path(model).name}"
    fields = {
        "role": role,
        "family": family,
        "view": view,
        "features": "all",
        "description": description,
    }
    library.record(directory, {key: fields})
    entry = {
        "file": str(path.relative_to(directory)),
        "sha256": library.file_hash(path),
        "algorithm": meta["policy_class"],
        "source": {"file": str(Path(model).resolve()), "sha256": library.file_hash(source)},
        "provenance": provenance(**library.provenance_hashes()),
    }
    library.record_entry(directory, key, entry)
    if games:
        mate = networks.load(partner or library.DEFAULT_PARTNER[role])
        entry["score"] = team_score(networks.load(key, root=directory), mate, range(games))
        library.record_entry(directory, key, entry)
    return entry
