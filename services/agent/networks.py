"""Playing library policies: numpy inference over their networks, and the rules for the heads a
network leaves alone.

Weights are plain arrays in `.npz` files read with `allow_pickle=False`, and inference is numpy:
loading a policy never executes code from a file and playing one needs no torch. A learned policy
chooses some heads (turn; or turn and thrust) with its network and leaves the others to rules;
every head spreads a small probability over its other choices (rules: EPSILON, networks: FLOOR
mixed into the softmax), so the joint distribution is never zero. A proxy (a network cloned from
recorded people, services/proxy) is played here too (`ProxyPolicy`); its files are proxy.py's.
"""

from __future__ import annotations

import json
import math
import random
import threading
from functools import cache
from pathlib import Path

import numpy as np

from services.agent.library import (
    FEATURES,
    OUTSIDE,
    PROXY_FAMILY,
    THRUST_RULES,
    Recipe,
    file_hash,
    manifest,
    registry,
)
from services.agent.policy import (
    Ending,
    RulePolicy,
    end_round_choice,
    end_stalled_rounds,
    factored_probs,
    factored_probs_batch,
    rule_head_probs,
    stalled,
)
from services.agent.scripted import SCRIPTED, MirrorShooter, good_shot, good_shot_batch
from services.sim import observation as ob
from shared.game import N_ACTIONS, N_FIRE, N_THRUST, N_TURN, GameConfig, Policy, join_action

FLOOR = 1e-3  # weight of the uniform mixed into a network head's softmax
HEADS = ("turn", "thrust", "fire")
HEAD_SIZES = {"turn": N_TURN, "thrust": N_THRUST, "fire": N_FIRE}
SPLITS = np.cumsum([HEAD_SIZES[h] for h in HEADS])[:-1]  # where each head's logits end


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


_READING = threading.Lock()


def read_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of an .npz file, never unpickling anything. One reader at a time: numpy parses
    each array's header with ast.literal_eval, and CPython 3.11 keeps the AST constructor's depth
    count per interpreter, so two threads loading at once (a pool's agent and adapter starting one
    match) can fail with "AST constructor recursion depth mismatch" (python/cpython#106905)."""
    with _READING, np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


class Network:
    """A multilayer perceptron held as numpy arrays: hidden layers with tanh or relu, linear out."""

    ACTIVATIONS = {"tanh": np.tanh, "relu": lambda h: np.maximum(h, 0.0)}

    def __init__(self, arrays: dict[str, np.ndarray], activation: str) -> None:
        n = len([k for k in arrays if k.startswith("w")])
        self.layers = [(arrays[f"w{i}"].astype(float), arrays[f"b{i}"].astype(float)) for i in range(n)]
        self.activation_name, self.activation = activation, self.ACTIVATIONS[activation]

    @classmethod
    def load(cls, path: Path) -> tuple[Network, dict]:
        """Weights and metadata from an .npz file; never unpickles anything."""
        arrays = read_arrays(path)
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
        self.alone: Stack | None = None  # this policy as a stack of one, for probs_batch

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def learned_heads(self, obs: np.ndarray) -> list[np.ndarray]:
        """Distributions of the learned heads for a batch of observations (rows)."""
        out = self.network(obs[..., self.features].astype(np.float64))
        return self.heads_of(out)

    def heads_of(self, out: np.ndarray) -> list[np.ndarray]:
        """The learned heads' distributions from the network's outputs (..., outputs)."""
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
        """probs() of every row of an (n, 64) array, with one network pass for all rows: a stack
        of one (`Stack`)."""
        if self.alone is None:  # made once: a stack's layers are copies of the network's
            self.alone = Stack([self])
        return self.alone(observations)[0]

    def act(self, obs: np.ndarray) -> int:
        heads = self.head_probs(obs)
        turn, thrust, fire = (draw(self.rng, heads[name]) for name in HEADS)
        return join_action(turn, thrust, fire)


class Stack:
    """Learned policies that differ only in their weights and how they were trained (`stack_key`:
    the same recipe shape, view, rule heads and network shape), evaluated as one: every network's
    layers as one batched product, the rule heads and the stalled rounds once for all. A library
    policy alone is a stack of one; a scorer of many members of one family (the partner
    population's PPO members) stacks them, and pays one pass where it paid one per policy."""

    def __init__(self, policies: list[LearnedPolicy]) -> None:
        if len({stack_key(p) for p in policies}) != 1 or stack_key(policies[0]) is None:
            raise ValueError(f"policies {[p.key for p in policies]} do not stack")
        self.first = policies[0]
        layers = zip(*(p.network.layers for p in policies), strict=True)
        self.layers = [  # (policies, in, out) weights, contiguous as the products read them
            (np.stack([w.T for w, _ in layer]), np.stack([b for _, b in layer])[:, None]) for layer in layers
        ]

    def __call__(self, observations: np.ndarray, ending: Ending | None = None) -> np.ndarray:
        """(policies, rows, 12): each policy's probs() of every row of an (n, 64) array (`ending`:
        end_round_batch of these rows, where the caller has it)."""
        first = self.first
        h = observations[:, first.features].astype(np.float64)[None]
        for i, (w, b) in enumerate(self.layers):
            h = np.matmul(h, w) + b
            if i < len(self.layers) - 1:
                h = first.network.activation(h)
        heads = dict(zip(first.recipe.learned, first.heads_of(h), strict=True))  # (policies, rows, n)
        for name, choices in rule_heads_batch(first.recipe, observations, first.config).items():
            heads[name] = rule_head_probs(choices, HEAD_SIZES[name], RulePolicy.EPSILON)[None]  # (1, rows, n)
        probs = factored_probs_batch(*(heads[name] for name in HEADS))
        return end_stalled_rounds(observations, first.view, probs, RulePolicy.EPSILON, ending)


def stack_key(policy: object) -> tuple | None:
    """What learned policies must share to be evaluated as one `Stack`; None for any other policy
    (a rule, a policy from outside)."""
    if type(policy) is not LearnedPolicy:
        return None
    r, net = policy.recipe, policy.network
    boltzmann = r.temperature if r.algorithm == "DQN" else None  # a DQN's one head
    shapes = tuple(w.shape for w, _ in net.layers)
    return (r.role, r.view, r.learned, r.features, r.speed_cap, r.thrust_rule, boltzmann, policy.config,
            net.activation_name, shapes)  # fmt: skip


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


def rule_variant(recipe: Recipe) -> RulePolicy:
    """A rule-based library policy: its family's scripted rule with the entry's `rule` settings
    (S4-S7: the mirror shooter with their own placement distances)."""
    if recipe.family not in SCRIPTED:  # a rule-based entry's family is its scripted rule
        families = list(SCRIPTED)
        raise ValueError(f"registry entry {recipe.key}: no rule for family {recipe.family!r}; {families}")
    policy = SCRIPTED[recipe.family](**recipe.rule)
    policy.key, policy.role = recipe.key, recipe.role
    return policy


def load(key: str, config: GameConfig | None = None, root: Path | None = None) -> Policy:
    """A library policy by key; a network's weights are checked against the manifest hash."""
    recipes = registry(root)
    if key not in recipes:
        raise KeyError(f"unknown library policy {key!r}; expected one of {list(recipes)}")
    recipe = recipes[key]
    if recipe.algorithm is None and recipe.family not in (OUTSIDE, PROXY_FAMILY):
        return rule_variant(recipe)
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
        return ProxyPolicy(key, recipe.role, network, recipe.view, meta.get("history", 0))
    return LearnedPolicy(recipe, network, config)


# --- a proxy: a network cloned from recorded people (services/proxy) -------------------------


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
    """A behaviour-cloned person: its network's three head distributions, each floored as FLOOR says,
    and the action's probability their product (exactly what the training maximised).

    One trained with history k (`tsf proxy train --history k`) also reads its own last k actions
    (one-hot, latest first): a person holds keys down, so the last action says much about the next.
    It remembers what it played since `reset`; `probs` is its distribution given that memory, and
    `probs_given` the distribution given any actions before (what the training scored)."""

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
