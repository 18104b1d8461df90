"""The exemplar policy library as data: B1-B9 (bait) and S1-S7 (shooter), their recipes and files.

`library/registry.toml` lists every policy's role, family and recipe; `library/manifest.json`
(written by `tsf train`) lists each trained policy's weights file with its hash, steps, seed, score
and the command that made it. This module reads them and hashes them (what a table, a job and a
recording are bound to) and never loads a network: playing a policy is networks.py (numpy
inference), and a seat's policy by key is seats.py.

Libraries of your own (made by `tsf library add`, services/training/loop.py) join the shipped one
when their directories are listed in TSF_LIBRARY (separated by the OS path separator): their keys
play, enter the table and the adapter's candidates like the shipped ones.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass, field, replace
from dataclasses import fields as dataclass_fields
from functools import cache
from pathlib import Path

from services.sim import observation as ob
from shared import config, provenance
from shared.errors import UsageError
from shared.files import write_json
from shared.game import OBS_SIZE, ROLES

LIBRARY = Path(__file__).parent / "library"
# Recipes trained into libraries of their own (`tsf train KEY --library DIR` adds the entry to DIR's
# registry), not members of the shipped library, its table or the adapter's candidates.
CANDIDATES = LIBRARY / "candidates.toml"
# Libraries shipped beside the study's, by the name TSF_LIBRARY may give instead of a directory:
# `grown` is the library grown for coverage by `tsf library grow` from the first population
# (GB1.., GS1..; docs/library.md, "The grown library"); `tuned` the one grown from its second version,
# with rule teammates tuned by search and groups the adapter can tell apart (TB1.., TS1..: the
# default agent's; "The tuned library"). `population` holds the partner population's trained members
# (PB01a.., PS01a..), which their cross-play and test figures name.
NAMED = {
    "grown": Path(__file__).parent / "grown",
    "tuned": Path(__file__).parent / "tuned",
    "population": Path(__file__).parents[1] / "population" / "members",
    "population-3": Path(__file__).parents[1] / "population" / "members-3",  # population-3.toml's
}
OUTSIDE = "outside"  # the family of a policy added from outside (a network over all 12 actions)
PROXY_FAMILY = "proxy"  # the family of a proxy added from recorded people (services/proxy)

# Feature sets: offsets into the 64-value observation (docs/observation.md) that a network reads.
_SELF = [ob.SELF + f for f in (ob.X, ob.Y, ob.VX, ob.VY, ob.COS, ob.SIN)]
_SHELLS2 = list(range(ob.SHELLS, ob.SHELLS + 2 * ob.PROJECTILE_SIZE))
# A bait also sees whether the fortress is up: a new round starts only once it leaves the region.
_UP = [ob.FORTRESS + ob.F_ALIVE]
_PARTNER = [ob.PARTNER + f for f in (ob.X, ob.Y, ob.VX, ob.VY)]
_FORTRESS = [ob.FORTRESS + f for f in (ob.F_COS, ob.F_SIN, ob.F_ALIVE, ob.F_VULNERABLE)]
# Rule thrust heads by the role that plays it unless a recipe names the other as its thrust_rule:
# "speed-cap" thrusts while under the recipe's speed cap, "mirror" as the mirror shooter capped at it.
THRUST_RULES = {"bait": "speed-cap", "shooter": "mirror"}
FEATURES: dict[str, list[int]] = {
    "self+shells": _SELF + _SHELLS2 + _UP,
    "self+shells+partner": _SELF + _SHELLS2 + _UP + _PARTNER,
    "shooter": _SELF + _PARTNER + [ob.PARTNER + ob.IN_REGION] + _FORTRESS,
    "all": list(range(OBS_SIZE)),
}
DEFAULT_PARTNER = {"bait": "S5", "shooter": "B5"}  # a strong partner for each seat (the env's, `add`'s)


@dataclass(frozen=True)
class Recipe:
    """One registry entry: what a policy is and, for a learned one, how it is trained."""

    key: str
    role: str
    family: str
    description: str
    algorithm: str | None = None  # A2C, PPO, TRPO, DQN; None for a rule-based policy
    learned: tuple[str, ...] = ()  # heads the network chooses
    features: str = ""
    view: str = "role"
    reward: str = ""
    weights: dict[str, float] = field(default_factory=dict)  # reward term weights
    speed_cap: float = 0.0  # px/frame, the thrust rule's cap
    thrust_rule: str = ""  # a rule thrust head's rule (THRUST_RULES); "" for the role's own
    temperature: float = 0.0  # DQN: softmax temperature over Q values
    steps: int = 0
    seed: int = 0
    partners: tuple[str, ...] = ()
    rule: dict[str, float] = field(default_factory=dict)  # a rule-based policy's parameters
    demonstrator: dict[str, float] = field(default_factory=dict)  # a bait's warm start (train.py)
    root: Path = field(default=LIBRARY, compare=False)  # the library directory it is listed in

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"{self.key}.role = {self.role!r}: one of {', '.join(ROLES)}")
        if self.algorithm and self.features not in FEATURES:
            raise ValueError(f"{self.key}.features = {self.features!r}: one of {', '.join(FEATURES)}")
        if self.thrust_rule not in ("", *THRUST_RULES.values()):
            rules = ", ".join(sorted(THRUST_RULES.values()))
            raise ValueError(f"{self.key}.thrust_rule = {self.thrust_rule!r}: one of {rules}, or none")
        if min(self.steps, self.temperature, self.speed_cap) < 0:
            raise ValueError(f"{self.key}: steps, temperature and speed_cap are 0 or more")


def roots() -> list[Path]:
    """The library directories: the shipped one, then those listed in TSF_LIBRARY: a directory, or
    the name of a library shipped beside the study's (NAMED: `TSF_LIBRARY=grown`) where no directory
    of that name is here."""
    extra = os.environ.get("TSF_LIBRARY", "")
    return [LIBRARY, *(_named(p) for p in extra.split(os.pathsep) if p)]


def _named(entry: str) -> Path:
    path = Path(entry)
    return NAMED[entry] if entry in NAMED and not path.is_dir() else path


def check_roots() -> None:
    """A UsageError for an entry of TSF_LIBRARY that names no library: checked as a command starts,
    since every later message (a missing calibration, a table of other libraries) would point into
    a directory that is not one."""
    for entry in filter(None, os.environ.get("TSF_LIBRARY", "").split(os.pathsep)):
        path = _named(entry)
        if not path.is_dir():
            raise UsageError(
                "TSF_LIBRARY", entry, "no such library", [*NAMED, "a directory with a registry.toml"]
            )
        if not (path / "registry.toml").is_file():
            raise UsageError("TSF_LIBRARY", entry, "is not a policy library (no registry.toml in it)")


def table_path() -> Path:
    """Where the self-play table of the libraries in use is: table.json in the last library directory
    (the shipped one without TSF_LIBRARY), since a table is bound to every library it measured."""
    return roots()[-1] / "table.json"


def calibration_path() -> Path:
    """Where the adapter's out-of-library thresholds are: beside the table, bound like it."""
    return roots()[-1] / "calibration.json"


def registry(root: Path | None = None) -> dict[str, Recipe]:
    """The recipes of the library at `root`, or of every library (roots()), by key in file order."""
    if root is not None:
        return _registry(Path(root))
    merged: dict[str, Recipe] = {}
    for path in roots():
        for key, recipe in _registry(path).items():
            if key in merged:
                raise UsageError("TSF_LIBRARY", path, f"lists {key}, a key of {merged[key].root} already")
            merged[key] = recipe
    return merged


def candidates() -> dict[str, Recipe]:
    """The candidate recipes (CANDIDATES): trained into a library of their own, not the shipped one's."""
    return _read(CANDIDATES, LIBRARY)


def adopt(root: Path, keys: list[str]) -> None:
    """Add the candidate recipes of `keys` that the library at `root` lacks to its registry, each
    entry's text as CANDIDATES writes it."""
    missing = [k for k in keys if k in candidates() and k not in registry(root)]
    if not missing:
        return
    sections: dict[str, list[str]] = {}
    for line in CANDIDATES.read_text().splitlines():
        header = re.match(r"^\[([A-Za-z][\w-]*)\]$", line)
        if header:
            sections[header[1]] = []
        if sections:
            sections[list(sections)[-1]].append(line)
    with open(root / "registry.toml", "a") as f:
        f.write("".join("\n" + "\n".join(sections[k]).strip() + "\n" for k in missing))
    forget()


@cache
def _registry(root: Path) -> dict[str, Recipe]:
    path = root / "registry.toml"
    if not path.exists():
        raise UsageError("TSF_LIBRARY", root, "is not a policy library (no registry.toml)")
    return _read(path, root)


def _read(path: Path, root: Path) -> dict[str, Recipe]:
    """A registry file, checked whole (every entry's keys, kinds and values) before any is used."""
    raw = config.load(path, "registry")
    try:
        return {key: _recipe(key, dict(entry), root) for key, entry in raw.items()}
    except ValueError as error:
        raise UsageError("registry", path, str(error)) from None


def _recipe(key: str, entry: dict, root: Path) -> Recipe:
    if "frame" in entry:  # the registry's name for the view; renaming it would unbind the table
        entry["view"] = entry.pop("frame")
    for name in ("key", "root") & entry.keys():
        raise ValueError(f"{key}.{name}: no such setting (the section's name is the key)")
    return replace(config.build(Recipe, entry | {"key": key}, f"{key}."), root=root)


def keys(role: str | None = None, root: Path | None = None) -> list[str]:
    """Library keys in registry order, optionally of one role (of the library at `root`, or of
    every library in use)."""
    return [k for k, r in registry(root).items() if role is None or r.role == role]


def manifest(root: Path | None = None) -> dict[str, dict]:
    """The training record of each trained policy: weights file, sha256, steps, seed, score, command
    (of the library at `root`, or of every library)."""
    entries: dict[str, dict] = {}
    for path in [root] if root else roots():
        file = Path(path) / "manifest.json"
        entries |= json.loads(file.read_text()) if file.exists() else {}
    return entries


def manifest_hash(root: Path | None = None) -> str:
    """Hash of the registries and manifests: what a table measured with these libraries is bound to
    (the shipped library alone hashes as it always has)."""
    paths = [Path(root)] if root else roots()
    h = hashlib.sha256()
    for path in paths:
        h.update((path / "registry.toml").read_bytes())
    h.update(json.dumps(manifest(root), sort_keys=True).encode())
    return h.hexdigest()[:16]


PLAYED = ("registry.toml", "manifest.json", "table.json", "calibration.json", "groups.json")


def play_hash() -> str:
    """Hash of everything a match may play from: the libraries in use and those shipped beside them
    (NAMED), each with the files an adaptive agent reads there (its table, calibration and partner
    groups). Two checkouts that agree on it play and adapt alike: a study's match hosts must."""
    h = hashlib.sha256()
    for root in dict.fromkeys([*roots(), *NAMED.values()]):
        for name in PLAYED:
            path = root / name
            h.update(f"{root.name}/{name}\0".encode())
            h.update(path.read_bytes() if path.exists() else b"")
    return h.hexdigest()[:16]


def provenance_hashes(table: Path | str | None = None) -> dict[str, str]:
    """The library's manifest hash ("unknown" where it cannot be read) and the table's file hash
    (default: the library's table; a string is taken as the table's name as it is), as
    provenance.provenance takes them."""
    try:
        manifest = manifest_hash()
    except (OSError, ValueError):
        manifest = "unknown"
    named = (
        table if isinstance(table, str) else provenance.file_hash(table_path() if table is None else table)
    )
    return {"library": manifest, "table": named}


def recipe_hash(recipe: Recipe) -> str:
    """Hash of a recipe's fields: a training checkpoint resumes only under the recipe it began with."""
    fields = {f.name: getattr(recipe, f.name) for f in dataclass_fields(recipe) if f.compare}  # not its root
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def copy(to: Path) -> Path:
    """A library at `to` that starts as the shipped one (registry, manifest, weights; not the table,
    the adapter's calibration or its skill model, which a retrained policy would make stale): where
    `tsf train` writes unless it is told to write the shipped library. A directory that already
    holds a registry is left as it is."""
    if not (to / "registry.toml").exists():
        shutil.copytree(
            LIBRARY,
            to,
            ignore=shutil.ignore_patterns("table.json*", "calibration.json", "skill.json", ".*"),
            dirs_exist_ok=True,
        )
    return to


def file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def learned(chosen: list[str]) -> list[str]:
    """The learned policies to train: `chosen` (UsageError for a key that is not one), or all
    of the library; a candidate recipe (CANDIDATES) is trained only when chosen."""
    trainable = [k for k, r in registry().items() if r.algorithm]
    if set(chosen) - set(trainable):
        trainable += [k for k in candidates() if k not in trainable]
    for key in chosen:
        if key not in trainable:
            raise UsageError("KEYS", key, "not a learned policy of the library", trainable)
    return chosen or trainable


# --- writing a library: every registry and manifest is written here --------------------------------


def forget() -> None:
    """Read the registries again when next asked: what a writer here does after writing one."""
    _registry.cache_clear()


def record(root: Path, recipes: dict[str, dict]) -> None:
    """Add the recipes (key -> fields) that the library at `root` lacks to the end of its registry,
    the directory made if need be; an entry it has is left as it is."""
    root.mkdir(parents=True, exist_ok=True)
    have = registry(root) if (root / "registry.toml").exists() else {}
    with open(root / "registry.toml", "a") as f:
        f.write("".join(_entry(key, fields) for key, fields in recipes.items() if key not in have))
    forget()


def write_registry(root: Path, recipes: dict[str, dict]) -> None:
    """The registry of the library at `root`, written over with exactly `recipes` (key -> fields)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "registry.toml").write_text("".join(_entry(key, fields) for key, fields in recipes.items()))
    forget()


def write_manifest(root: Path, entries: dict[str, dict]) -> None:
    """The manifest of the library at `root`, written whole (shared/files.py) with exactly `entries`."""
    write_json(root / "manifest.json", entries)


def copy_member(source: Path, entry: dict, target: Path, key: str) -> dict:
    """A trained policy's weights (its manifest `entry` in the library at `source`) copied into the
    library at `target` as `key`; its manifest entry there, naming the new file and its hash."""
    path = target / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source / entry["file"], path)
    return entry | {"file": str(path.relative_to(target)), "sha256": file_hash(path)}


def adopt_members(source: Path, target: Path, keys: list[str]) -> None:
    """The trained `keys` of the library at `source` copied into the library at `target` (weights and
    manifest entries; its registry lists them already)."""
    entries, have = manifest(source), manifest(target)
    write_manifest(target, have | {key: copy_member(source, entries[key], target, key) for key in keys})


def _entry(key: str, fields: dict) -> str:
    """One registry entry as TOML (strings, numbers, booleans, lists, tables of numbers)."""

    def value(v: object) -> str:
        if isinstance(v, str):
            return json.dumps(v)  # a JSON string is a TOML basic string
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"{key}: cannot write {v!r} to a registry")

    return f"\n[{key}]\n" + "".join(f"{name} = {value(v)}\n" for name, v in fields.items())


def record_entry(out: Path, key: str, entry: dict) -> None:
    """Write one manifest entry; a lock keeps parallel trainings from losing each other's."""
    with open(out / ".manifest.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = out / "manifest.json"
        entries = json.loads(path.read_text()) if path.exists() else {}
        entries[key] = entry
        path.write_text(json.dumps(entries, indent=2, sort_keys=True) + "\n")
