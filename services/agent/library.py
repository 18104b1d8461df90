"""The exemplar policy library: B1-B9 (bait) and S1-S7 (shooter), loaded by key.

`library/registry.toml` lists every policy's role, family and recipe; `library/manifest.json`
(written by `tsf train`) lists each trained policy's weights file with its hash, steps, seed, score
and the command that made it. Weights are plain arrays in `.npz` files read with
`allow_pickle=False`, and inference is numpy: loading a policy never executes code from a file and
playing one needs no torch.

Libraries of your own (made by `tsf library add`, services/agent/outside.py) join the shipped one
when their directories are listed in TSF_LIBRARY (separated by the OS path separator): their keys
play, enter the table and the adapter's candidates like the shipped ones. Outside a library, a
policy key may also be an SB3 `.zip` or a `package.module:attr` object (outside.py).

A learned policy chooses some heads (turn; or turn and thrust) with its network and leaves the
others to rules; every head spreads a small probability over its other choices (rules: EPSILON,
networks: FLOOR mixed into the softmax), so the joint distribution is never zero.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import shutil
import tomllib
from dataclasses import dataclass, field
from dataclasses import fields as dataclass_fields
from functools import cache
from pathlib import Path

import numpy as np

from services.agent import outside
from services.agent.policy import (
    RulePolicy,
    end_round_choice,
    end_stalled_rounds,
    factored_probs,
    factored_probs_batch,
    rule_head_probs,
    stalled,
)
from services.agent.scripted import MirrorShooter, good_shot, good_shot_batch, scripted_keys, scripted_policy
from services.sim import observation as ob
from shared.errors import UsageError
from shared.game import N_FIRE, N_THRUST, N_TURN, OBS_SIZE, ROLES, GameConfig, Policy, join_action

LIBRARY = Path(__file__).parent / "library"
OUTSIDE = "outside"  # the family of a policy added from outside (a network over all 12 actions)
PROXY_FAMILY = "proxy"  # the family of a proxy added from recorded people (services/proxy)
FLOOR = 1e-3  # weight of the uniform mixed into a network head's softmax
HEADS = ("turn", "thrust", "fire")
HEAD_SIZES = {"turn": N_TURN, "thrust": N_THRUST, "fire": N_FIRE}

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


def roots() -> list[Path]:
    """The library directories: the shipped one, then those listed in TSF_LIBRARY."""
    extra = os.environ.get("TSF_LIBRARY", "")
    return [LIBRARY, *(Path(p) for p in extra.split(os.pathsep) if p)]


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


@cache
def _registry(root: Path) -> dict[str, Recipe]:
    path = root / "registry.toml"
    if not path.exists():
        raise UsageError("TSF_LIBRARY", root, "is not a policy library (no registry.toml)")
    with open(path, "rb") as f:
        raw = tomllib.load(f)
    recipes = {}
    for key, entry in raw.items():
        entry = {k: tuple(v) if isinstance(v, list) else v for k, v in entry.items()}
        if "frame" in entry:  # the registry's name for the view; renaming it would unbind the table
            entry["view"] = entry.pop("frame")
        recipe = Recipe(key=key, root=root, **entry)
        if recipe.role not in ROLES:
            raise ValueError(f"registry entry {key}: unknown role {recipe.role!r}")
        if recipe.algorithm and recipe.features not in FEATURES:
            raise ValueError(f"registry entry {key}: unknown feature set {recipe.features!r}")
        if recipe.thrust_rule not in ("", *THRUST_RULES.values()):
            rule, expected = recipe.thrust_rule, sorted(THRUST_RULES.values())
            raise ValueError(f"registry entry {key}: unknown thrust_rule {rule!r}; expected {expected}")
        recipes[key] = recipe
    return recipes


def keys(role: str | None = None) -> list[str]:
    """Library keys in registry order, optionally of one role."""
    return [k for k, r in registry().items() if role is None or r.role == role]


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


def recipe_hash(recipe: Recipe) -> str:
    """Hash of a recipe's fields: a training checkpoint resumes only under the recipe it began with."""
    fields = {f.name: getattr(recipe, f.name) for f in dataclass_fields(recipe) if f.compare}  # not its root
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def copy(to: Path) -> Path:
    """A library at `to` that starts as the shipped one (registry, manifest, weights; not the table
    or the adapter's calibration, which a retrained policy would make stale): where `tsf train`
    writes unless it is told to write the shipped library. A directory that already holds a registry
    is left as it is."""
    if not (to / "registry.toml").exists():
        shutil.copytree(
            LIBRARY,
            to,
            ignore=shutil.ignore_patterns("table.json*", "calibration.json", ".*"),
            dirs_exist_ok=True,
        )
    return to


def file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --- rules for the heads a network leaves alone ------------------------------------------------


def speed(obs: np.ndarray) -> float:
    return math.hypot(float(obs[ob.SELF + ob.VX]), float(obs[ob.SELF + ob.VY])) * ob.VELOCITY_SCALE


def speed_capped(recipe: Recipe) -> bool:
    """Whether the recipe's rule thrust is the speed cap (a bait's own rule, the study's RL
    shooters' by their description) rather than the mirror shooter's (a shooter's own)."""
    return (recipe.thrust_rule or THRUST_RULES[recipe.role]) == "speed-cap"


def rule_heads(recipe: Recipe, obs: np.ndarray, config: GameConfig) -> dict[str, int]:
    """The rule's choice for every head the network does not choose.

    Thrust: while under the recipe's speed cap (speed_capped), or as the mirror shooter with the
    recipe's speed cap would (toward the point opposite the bait, holding once there). Fire: never
    for a bait; a shooter fires when the shot is good (scripted.good_shot). Shooter rules read the
    world view."""
    out = {}
    if "thrust" not in recipe.learned:
        if speed_capped(recipe):
            out["thrust"] = int(speed(obs) < recipe.speed_cap)
        else:
            out["thrust"] = _mirror(recipe.speed_cap, config).choose(obs)[1]
    if "fire" not in recipe.learned:
        out["fire"] = 0 if recipe.role == "bait" else int(good_shot(obs, config, 4.0, 40.0))
    return out


def rule_heads_batch(recipe: Recipe, observations: np.ndarray, config: GameConfig) -> dict[str, np.ndarray]:
    """rule_heads() of every row: each head's (rows,) choices."""
    out = {}
    if "thrust" not in recipe.learned:
        if speed_capped(recipe):
            v = observations[:, [ob.SELF + ob.VX, ob.SELF + ob.VY]].astype(np.float64)
            capped = np.hypot(v[:, 0], v[:, 1]) * ob.VELOCITY_SCALE < recipe.speed_cap
            out["thrust"] = capped.astype(np.int64)
        else:
            out["thrust"] = _mirror(recipe.speed_cap, config).choose_batch(observations)[:, 1]
    if "fire" not in recipe.learned:
        if recipe.role == "bait":
            out["fire"] = np.zeros(len(observations), np.int64)
        else:
            out["fire"] = good_shot_batch(observations, config, 4.0, 40.0).astype(np.int64)
    return out


@cache
def _mirror(max_speed: float, config: GameConfig) -> MirrorShooter:
    return MirrorShooter(max_speed=max_speed, config=config)


# --- the network ---------------------------------------------------------------------------------


class Network:
    """A multilayer perceptron held as numpy arrays: hidden layers with tanh or relu, linear out."""

    ACTIVATIONS = {"tanh": np.tanh, "relu": lambda h: np.maximum(h, 0.0)}

    def __init__(self, arrays: dict[str, np.ndarray], activation: str) -> None:
        n = len([k for k in arrays if k.startswith("w")])
        self.layers = [(arrays[f"w{i}"].astype(float), arrays[f"b{i}"].astype(float)) for i in range(n)]
        self.activation = self.ACTIVATIONS[activation]

    @classmethod
    def load(cls, path: Path) -> tuple[Network, dict]:
        """Weights and metadata from an .npz file; never unpickles anything."""
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(bytes(arrays.pop("meta")).decode())
        return cls(arrays, meta["activation"]), meta

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Outputs for one input row or a batch of rows."""
        h = x
        for w, b in self.layers[:-1]:
            h = self.activation(h @ w.T + b)
        w, b = self.layers[-1]
        return h @ w.T + b


def softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)


def _rule_distributions(choices: dict[str, int]) -> dict[str, np.ndarray]:
    """Each head's distribution for a rule's choice: the choice with 1 - EPSILON, the rest spread."""
    return {
        name: rule_head_probs(np.array([c]), HEAD_SIZES[name], RulePolicy.EPSILON)[0]
        for name, c in choices.items()
    }


class LearnedPolicy:
    """A trained library policy: network heads plus rule heads, sampled independently."""

    def __init__(self, recipe: Recipe, network: Network, config: GameConfig | None = None) -> None:
        self.recipe, self.network = recipe, network
        self.key, self.role, self.view = recipe.key, recipe.role, recipe.view
        self.config = config or GameConfig()
        self.features = np.array(FEATURES[recipe.features])
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def learned_heads(self, obs: np.ndarray) -> list[np.ndarray]:
        """Distributions of the learned heads for a batch of observations (rows)."""
        out = self.network(obs[..., self.features].astype(np.float64))
        if self.recipe.algorithm == "DQN":  # one head; Q values -> Boltzmann distribution
            return [self._floor(softmax(out / self.recipe.temperature))]
        heads, start = [], 0
        for name in self.recipe.learned:
            n = HEAD_SIZES[name]
            heads.append(self._floor(softmax(out[..., start : start + n])))
            start += n
        return heads

    @staticmethod
    def _floor(p: np.ndarray) -> np.ndarray:
        return (1.0 - FLOOR) * p + FLOOR / p.shape[-1]

    def rule_head_probs(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """The rule heads' distributions: the rule's choice with 1 - EPSILON, the rest spread."""
        return _rule_distributions(rule_heads(self.recipe, obs, self.config))

    def head_probs(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """Every head's distribution; in a stalled round the end-round rule's (policy.stalled)."""
        if stalled(obs):
            return _rule_distributions(
                dict(zip(HEADS, end_round_choice(obs, self.view == "world"), strict=True))
            )
        learned = dict(zip(self.recipe.learned, self.learned_heads(obs), strict=True))
        return learned | self.rule_head_probs(obs)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        heads = self.head_probs(obs)
        return factored_probs(*(heads[name] for name in HEADS))

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        """probs() of every row of an (n, 64) array, with one network pass for all rows."""
        heads = dict(zip(self.recipe.learned, self.learned_heads(observations), strict=True))
        for name, choices in rule_heads_batch(self.recipe, observations, self.config).items():
            heads[name] = rule_head_probs(choices, HEAD_SIZES[name], RulePolicy.EPSILON)
        probs = factored_probs_batch(*(heads[name] for name in HEADS))
        return end_stalled_rounds(observations, self.view, probs, RulePolicy.EPSILON)

    def act(self, obs: np.ndarray) -> int:
        heads = self.head_probs(obs)
        turn, thrust, fire = (draw(self.rng, heads[name]) for name in HEADS)
        return join_action(turn, thrust, fire)


def draw(rng: random.Random, p: np.ndarray) -> int:
    """An index drawn from the distribution p with one uniform of rng."""
    u, total = rng.random(), 0.0
    for i, pi in enumerate(p):
        total += pi
        if u < total:
            return i
    return len(p) - 1


class JointPolicy:
    """A network over the whole observation that scores all 12 actions (a policy from outside the
    library: outside.py). Its distribution is the network's softmax with FLOOR mixed in; act()
    draws from exactly that, so probs() is what the adapter's likelihoods need."""

    def __init__(self, key: str, role: str, view: str, network: Network) -> None:
        self.key, self.role, self.view, self.network = key, role, view, network
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        return LearnedPolicy._floor(softmax(self.network(observations.astype(np.float64))))

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return self.probs_batch(obs[None])[0]

    def act(self, obs: np.ndarray) -> int:
        return draw(self.rng, self.probs(obs))


class MirrorVariant(MirrorShooter):
    """A rule-based library shooter: the mirror shooter with its own placement distance."""

    def __init__(self, recipe: Recipe) -> None:
        super().__init__(**recipe.rule)
        self.key, self.role, self.view = recipe.key, recipe.role, "world"


def load(key: str, config: GameConfig | None = None, root: Path | None = None) -> Policy:
    """A library policy by key; a network's weights are checked against the manifest hash."""
    recipes = registry(root)
    if key not in recipes:
        raise KeyError(f"unknown library policy {key!r}; expected one of {list(recipes)}")
    recipe = recipes[key]
    if recipe.algorithm is None and recipe.family not in (OUTSIDE, PROXY_FAMILY):
        return MirrorVariant(recipe)
    entry = manifest(recipe.root).get(key)
    path = recipe.root / entry["file"] if entry else None
    if path is None or not path.exists():
        raise FileNotFoundError(
            f"library policy {key} is not trained yet: run `tsf train {key} --out {root}`"
        )
    if file_hash(path) != entry["sha256"]:
        raise ValueError(f"{path} does not match its manifest hash; retrain {key} or restore the file")
    network, meta = Network.load(path)
    if recipe.family == OUTSIDE:
        return JointPolicy(key, recipe.role, recipe.view, network)
    if recipe.family == PROXY_FAMILY:
        from services.agent.proxy import ProxyPolicy

        return ProxyPolicy(key, recipe.role, network, recipe.view, meta.get("history", 0))
    return LearnedPolicy(recipe, network, config)


def seat_keys(role: str) -> list[str]:
    """Every key that can play `role`'s seat: the library's policies of that role, then the scripted ones."""
    return [*keys(role), *scripted_keys(role)]


def learned(chosen: list[str]) -> list[str]:
    """The learned policies to train: `chosen` (UsageError for a key that is not one), or all."""
    trainable = [k for k, r in registry().items() if r.algorithm]
    for key in chosen:
        if key not in trainable:
            raise UsageError("KEYS", key, "not a learned policy of the library", trainable)
    return chosen or trainable


def check_seat(key: str, role: str, option: str = "--policy") -> None:
    """Refuse (UsageError) a seat that is not one, or a key that cannot play it: the line names the
    option, the value and every key that can. A policy from outside (outside.py) is loaded to see
    which seat it plays."""
    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if outside.is_outside(key):
        outside.load(key, role, option)
        return
    if key not in seat_keys(role):
        other = [r for r in ROLES if key in seat_keys(r)]
        problem = f"plays the {other[0]} seat, not the {role}" if other else f"no policy of the {role} seat"
        raise UsageError(option, key, problem, seat_keys(role))


def policy_for(key: str, role: str, option: str = "--policy") -> Policy:
    """Any policy a seat can play, by key: a library policy (B1-B9, S1-S7, and those of TSF_LIBRARY),
    a scripted one, an SB3 `.zip` or a `module:attr` (outside.py); a key that cannot play the seat is
    a UsageError about `option` (check_seat)."""
    if outside.is_outside(key):
        return outside.load(key, role, option)
    check_seat(key, role, option)
    return load(key) if key in registry() else scripted_policy(key, role)
