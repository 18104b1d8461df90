"""Partners in bulk: a partner (partners.py) in many lanes of a batched game at once.

`lanes(partners)` is the batched form of partners of one shape (`shape`: the same wrappers with
the same settings, nested the same way, whatever policies they wrap): each wrapper of partners.py
does what it does there, in arrays (noisy, delayed, sticky, switch), and the project policies
inside (library, scripted, random) draw from their distributions, each policy asked once a frame
for all the lanes it plays in, as batch_play does. So `noisy(switch(B1,B5))` and
`noisy(switch(B7,B2))` share one batched form, and a frame costs one call per policy, not per
partner. A human-like partner of project policies (`human(B5)`, `human(B1,B5)`) plays its own
batched form, `HumanLike.act_lanes`, which gives each lane the very actions of the scalar partner
of the same seed. A partner of any other kind (a plug-in `module:attr`, a kind this module does
not know, a human-like hand on a wrapper) is played as it is: one copy per lane, reset and asked
lane by lane as in a scalar game, so it is exact, only slower.

The draws of a policy and of each wrapper come from their own stream of `lane_uniforms`, keyed by
the game's seed: a game's partner depends on its seed, never on which lanes share the batch. They
are not the scalar partner's `random.Random` draws, so a batched game agrees with the scalar game
of the same seed in distribution, not draw for draw.
"""

from __future__ import annotations

import copy
import itertools
from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np

from services.adapter.human_like import HumanLike
from services.adapter.partners import (
    Delayed,
    Noisy,
    Partner,
    PartnerError,
    Sticky,
    Switching,
    ask,
    make_partner,
)
from services.agent.networks import LearnedPolicy
from services.agent.policy import RulePolicy, UniformPolicy
from services.sim.batch_play import act_lanes
from services.sim.play import policy_seed
from services.sim.sampling import lane_uniforms
from shared.game import N_ACTIONS, ROLES


class Lanes(Protocol):
    """A partner in n lanes: reset with each lane's game seed, then one action per lane per frame."""

    view: str

    def reset(self, keys: np.ndarray) -> None: ...

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray: ...


class PolicyLanes:
    """Project policies of one view, one per lane: each policy's distributions for its lanes,
    sampled with the lanes' draws."""

    def __init__(self, policies: list[Partner], stream: int) -> None:
        self.policies = list({id(p): p for p in policies}.values())
        self.choice = np.array([[id(q) for q in self.policies].index(id(p)) for p in policies])
        self.view, self.stream = policies[0].view, stream

    def reset(self, keys: np.ndarray) -> None:
        self.keys = keys

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        uniforms = lane_uniforms(self.keys, self.stream, frame)
        return act_lanes(self.policies, self.choice, lambda view: obs, uniforms)


class NoisyLanes:
    """partners.Noisy: a uniformly random action with probability `noise`, lane by lane."""

    def __init__(self, inner: Lanes, noise: float, streams: Iterator[int]) -> None:
        self.inner, self.noise, self.view = inner, noise, inner.view
        self.slip, self.pick = next(streams), next(streams)

    def reset(self, keys: np.ndarray) -> None:
        self.inner.reset(keys)
        self.keys = keys

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        action = self.inner.act(obs, frame)
        slipped = lane_uniforms(self.keys, self.slip, frame) < self.noise
        random = (lane_uniforms(self.keys, self.pick, frame) * N_ACTIONS).astype(np.int64)
        return np.where(slipped, random, action)


class DelayedLanes:
    """partners.Delayed: the inner partner acts on each lane's observation of `delay` frames ago
    (the first one until that many have been seen)."""

    def __init__(self, inner: Lanes, delay: int) -> None:
        self.inner, self.delay, self.view = inner, delay, inner.view

    def reset(self, keys: np.ndarray) -> None:
        self.inner.reset(keys)
        self.seen: np.ndarray | None = None
        self.t = 0

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        kept = self.delay + 1
        if self.seen is None:
            self.seen = np.empty((kept, *obs.shape), obs.dtype)
        self.seen[self.t % kept] = obs
        oldest = max(0, self.t - self.delay)
        self.t += 1
        return self.inner.act(self.seen[oldest % kept], frame)


class StickyLanes:
    """partners.Sticky: each lane repeats its previous action with probability `sticky`."""

    def __init__(self, inner: Lanes, sticky: float, streams: Iterator[int]) -> None:
        self.inner, self.sticky, self.view = inner, sticky, inner.view
        self.stream = next(streams)

    def reset(self, keys: np.ndarray) -> None:
        self.inner.reset(keys)
        self.keys, self.last = keys, np.zeros(len(keys), np.int64)

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        action = self.inner.act(obs, frame)  # the inner partner keeps its own course either way
        self.last = np.where(lane_uniforms(self.keys, self.stream, frame) >= self.sticky, action, self.last)
        return self.last


class SwitchLanes:
    """partners.Switching: the first partner for `at` frames, then the second."""

    def __init__(self, first: Lanes, second: Lanes, at: int) -> None:
        self.first, self.second, self.at, self.view = first, second, at, first.view

    def reset(self, keys: np.ndarray) -> None:
        self.first.reset(keys)
        self.second.reset(keys)
        self.t = 0

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        self.t += 1
        return (self.first if self.t <= self.at else self.second).act(obs, frame)


class HumanLanes:
    """human_like.HumanLike, whose `act_lanes` is its batched form: every lane gets the actions
    `act` gives the scalar game of the same seed (reset with that game's seed, `offset` added)."""

    def __init__(self, partner: HumanLike, offset: int = 0) -> None:
        self.partner, self.offset, self.view = partner, offset, partner.view
        self.key, self.role = partner.key, partner.role

    def reset(self, keys: np.ndarray) -> None:
        self.partner.reset_lanes(self._seeds(keys))

    def restart(self, lanes: np.ndarray, keys: np.ndarray) -> None:
        """New games of seeds `keys` in `lanes` while the others play on (a training env's)."""
        self.partner.restart_lanes(lanes, self._seeds(keys))

    def _seeds(self, keys: np.ndarray) -> list[int]:
        return [policy_seed(key, self.partner.role) + self.offset for key in np.asarray(keys).tolist()]

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        return self.partner.act_lanes(obs)


class EachLane:
    """Any other partners, as they are: a copy per lane, reset with the scalar game's seed
    (`offset` added, as a switch's second partner gets) and asked lane by lane."""

    def __init__(self, partners: list[Partner], offset: int = 0) -> None:
        self.partners, self.offset, self.view = partners, offset, partners[0].view

    def reset(self, keys: np.ndarray) -> None:
        self.copies = [copy.deepcopy(p) for p in self.partners]
        for partner, key in zip(self.copies, keys.tolist(), strict=True):
            partner.reset(policy_seed(key, partner.role) + self.offset)

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        return np.array(
            [ask(p, row, frame, lane) for lane, (p, row) in enumerate(zip(self.copies, obs, strict=True))],
            np.int64,
        )


# A policy whose act() draws from its probs() is played from its distributions.
_SAMPLED = (LearnedPolicy.act, RulePolicy.act, UniformPolicy.act)
_SETTING = {Noisy: "noise", Delayed: "delay", Sticky: "sticky", Switching: "at"}


def shape(partner: Partner) -> tuple:
    """What a partner's batched form depends on: its wrappers, their settings and nesting, and the
    view of the policies inside, not which policies they are."""
    kind = type(partner)
    if kind in _SETTING:
        inner = (shape(partner.inner), *([shape(partner.second)] if kind is Switching else []))
        return (kind.__name__, getattr(partner, _SETTING[kind]), *inner)
    if kind is HumanLike and all(_sampled(p) for p in (partner.first, partner.second) if p is not None):
        return ("HumanLike", partner.key)  # one batched form per pair of policies (HumanLanes)
    return ("policy" if _sampled(partner) else "other", partner.view)


def _sampled(partner: Partner) -> bool:
    return getattr(type(partner), "act", None) in _SAMPLED


def lanes(partners: list[Partner], stream: int, streams: Iterator[int], offset: int = 0) -> Lanes:
    """The batched form of `partners` (one per lane, all of one `shape`): their policies draw from
    `stream`, every other draw of the wrappers from the next of `streams` (unique in one form)."""
    kind, first = type(partners[0]), partners[0]
    inner = [p.inner for p in partners] if kind in _SETTING else []
    if kind is Noisy:
        return NoisyLanes(lanes(inner, stream, streams, offset), first.noise, streams)
    if kind is Delayed:
        return DelayedLanes(lanes(inner, stream, streams, offset), first.delay)
    if kind is Sticky:
        return StickyLanes(lanes(inner, stream, streams, offset), first.sticky, streams)
    if kind is Switching:
        second = lanes([p.second for p in partners], next(streams), streams, offset + 1)
        return SwitchLanes(lanes(inner, stream, streams, offset), second, first.at)
    if shape(first)[0] == "HumanLike":
        return HumanLanes(first, offset)
    if shape(first)[0] == "policy":
        return PolicyLanes(partners, stream)
    return EachLane(partners, offset)


class Partners:
    """Every lane's partner, by name: the lanes of partners of one shape are played by one
    batched form."""

    def __init__(self, names: list[str], role: str, keys: np.ndarray) -> None:
        made = {name: make_partner(name, role) for name in dict.fromkeys(names)}
        shapes = [shape(made[name]) for name in names]
        self.groups: list[tuple[np.ndarray, Lanes]] = []
        for kind in dict.fromkeys(shapes):
            rows = np.array([lane for lane, s in enumerate(shapes) if s == kind])
            # streams 0 and 1 are the seats' (batch_play); a partner's wrappers draw from 2 on
            partner = lanes([made[names[lane]] for lane in rows], ROLES.index(role), itertools.count(2))
            partner.reset(np.asarray(keys)[rows])
            self.groups.append((rows, partner))

    def act(self, observed: Callable[[str], np.ndarray], frame: int) -> np.ndarray:
        """Every lane's action; `observed(view)`: every lane's observation of the partner's seat."""
        out = np.empty(sum(len(rows) for rows, _ in self.groups), np.int64)
        for rows, partner in self.groups:
            try:
                out[rows] = partner.act(observed(partner.view)[rows], frame)
            except PartnerError as error:  # its lane in this batch, not in its group
                raise PartnerError(error.problem, int(rows[error.lane])) from None
        return out
