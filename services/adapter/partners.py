"""Partners for evaluating an adaptive agent: library policies and stand-ins for humans built from them.

A partner is named by a small grammar, so that an evaluation's partners can be rebuilt by name in
any worker process:

    B5                 a library (or scripted) policy as it is
    noisy(B5)          plays a uniformly random action with probability NOISE per frame
    delayed(B5)        acts on the state of DELAY frames ago (a reaction time of 0.2 s);
                       delayed(B5,frames=2) of 2 frames ago
    sticky(B5)         repeats its previous action with probability STICKY (keys held too long)
    switch(B5,B7)      plays B5 until SWITCH_AT, then B7 (a partner who changes style mid-game)
    human(B5)          B5 played by a simulated hand: reaction delay, held keys, lapses, slips
    human(B1,B5)       the same, drifting from B1's style to B5's over a session (human_like.py)
    human(B5,skill=novice)  a first-time player (skill: novice, typical (the default), practised,
                       or a number in [0, 1]); input_ms=N: the screen and keys' delay (default:
                       the study page's, 33; input_ms=0 for none)
    circle(radius=150,speed=3)  a scripted rule with other settings (any of its constructor's
                       numbers): a hand-written partner whose style no library policy has
    package.module:attr  your own partner: an object with the policy protocol's key, role, view,
                         reset(seed) and act(obs), or a callable that returns a new one
    my_bait.zip          a model trained with Stable-Baselines3 (services/agent/outside.py)
    proxy:DIR            a proxy cloned from recorded people (`tsf proxy train`, services/proxy)
    humans:DIR@NAME      participant NAME's stand-in fitted from recordings (`tsf humans fit`;
                         humans:DIR when DIR holds one participant)

Wrappers nest: `noisy(switch(B5,B7))`.
"""

from __future__ import annotations

import json
import random
from collections import deque
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from services.adapter.human_like import STAND_INS, HumanLike
from services.adapter.seat import ADAPTIVE_KIND, FITTED, HUMANS, KEY, PERSON, PROXY_KIND, RULE, SeatSpec
from services.agent import library
from services.agent.scripted import SCRIPTED
from services.agent.seats import policy_for
from services.sim.engine import Game
from services.sim.observation import as_observation, world_values
from shared.errors import Failure, UsageError
from shared.game import N_ACTIONS, checked_action

NOISE = 0.1
DELAY = 6  # frames
STICKY = 0.5
SWITCH_AT = 900  # frame: the middle of a one-minute game


@runtime_checkable
class Partner(Protocol):
    """What a partner needs of the policy protocol: it acts, it need not report probabilities."""

    key: str
    role: str
    view: str

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs: np.ndarray) -> int: ...


class Wrapper:
    """A partner that changes how an inner partner acts; reset seeds both."""

    def __init__(self, inner: Partner, key: str) -> None:
        self.inner, self.key = inner, key
        self.role, self.view = inner.role, inner.view
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.inner.reset(seed)
        self.rng = random.Random(None if seed is None else seed * 7919 + 1)


class Noisy(Wrapper):
    def __init__(self, inner: Partner, noise: float = NOISE) -> None:
        super().__init__(inner, f"noisy({inner.key})")
        self.noise = noise

    def act(self, obs: np.ndarray) -> int:
        action = self.inner.act(obs)
        return self.rng.randrange(N_ACTIONS) if self.rng.random() < self.noise else action


class Delayed(Wrapper):
    def __init__(self, inner: Partner, delay: int = DELAY) -> None:
        super().__init__(
            inner, f"delayed({inner.key})" if delay == DELAY else f"delayed({inner.key},frames={delay})"
        )
        self.delay = delay
        self.seen: deque[np.ndarray] = deque(maxlen=delay + 1)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.seen.clear()

    def act(self, obs: np.ndarray) -> int:
        self.seen.append(obs)
        return self.inner.act(self.seen[0])  # the oldest kept: `delay` frames ago once full


class Sticky(Wrapper):
    def __init__(self, inner: Partner, sticky: float = STICKY) -> None:
        super().__init__(inner, f"sticky({inner.key})")
        self.sticky, self.last = sticky, 0

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.last = 0

    def act(self, obs: np.ndarray) -> int:
        action = self.inner.act(obs)  # the inner partner keeps its own course either way
        if self.rng.random() >= self.sticky:
            self.last = action
        return self.last


class Switching(Wrapper):
    def __init__(self, first: Partner, second: Partner, at: int = SWITCH_AT) -> None:
        if first.role != second.role or first.view != second.view:
            raise ValueError(f"switch({first.key},{second.key}): both must share role and observation view")
        super().__init__(first, f"switch({first.key},{second.key})")
        self.second, self.at, self.t = second, at, 0

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.second.reset(None if seed is None else seed + 1)
        self.t = 0

    def act(self, obs: np.ndarray) -> int:
        self.t += 1
        return (self.inner if self.t <= self.at else self.second).act(obs)


class PartnerError(Failure):
    """A partner that raised, or answered no action, during a game: which, when and why. It would
    fail again with the same inputs, so a job that meets it ends the run (services/jobs)."""

    def __init__(self, problem: str, lane: int = 0) -> None:
        super().__init__(problem)
        self.problem, self.lane = problem, lane


def ask(partner: Partner, obs: np.ndarray, frame: int, lane: int = 0) -> int:
    """The partner's action for `obs`, checked; a PartnerError naming it if it raises or answers
    something that is no action."""
    try:
        return checked_action(partner.act(obs))
    except Exception as error:  # noqa: BLE001 - a partner from outside may raise anything
        problem = f"{partner.key} at frame {frame}: {type(error).__name__}: {error}"
        raise PartnerError(problem[:240], lane) from None


def check_partner(name: str, role: str, option: str = "--partner") -> None:
    """Build the partner `name` and ask it for one action on a fresh game's first state, as a run
    does before handing out any job: a mistake in the name, a plug-in that does not import, is
    no policy, plays the other seat or cannot answer is one UsageError here, not a failed job."""
    try:
        partner = make_partner(name, role)
        partner.reset(0)
        ask(partner, as_observation(world_values(Game(), role), partner.view), 0)
    except UsageError:
        raise
    except Exception as error:  # noqa: BLE001 - a partner from outside may raise anything
        problem = getattr(error, "problem", None) or f"{type(error).__name__}: {error}"
        raise UsageError(option, name, problem) from None


WRAPPERS = {"noisy": Noisy, "delayed": Delayed, "sticky": Sticky}


def make_partner(name: str, role: str) -> Partner:
    """A fresh partner of `role` by name (see the module docstring for the grammar)."""
    return build(SeatSpec.parse(name, "--partner"), role)


def build(spec: SeatSpec, role: str, option: str = "--partner") -> Partner:
    """What plays `role`'s seat as `spec` says, fresh: a policy, or a partner made of policies. A
    person or an adaptive agent is no partner (UsageError): a gateway or the adapter plays them."""
    if spec.kind == "delayed" and spec.settings:
        (setting, frames), *more = spec.settings
        if more or setting != "frames" or not frames.isdigit() or int(frames) > 60:
            raise UsageError(option, str(spec), "delayed(...) takes one setting, frames=N (0 to 60)")
        return Delayed(build(spec.inner[0], role, option), int(frames))
    if spec.kind in WRAPPERS:
        return WRAPPERS[spec.kind](build(spec.inner[0], role, option))
    if spec.kind == "human":
        inner = [build(partner, role, option) for partner in spec.inner]
        try:
            return HumanLike.from_arguments(inner, [f"{name}={value}" for name, value in spec.settings])
        except ValueError as error:
            raise UsageError(option, str(spec), str(error)) from None
    if spec.kind == "switch":
        return Switching(build(spec.inner[0], role, option), build(spec.inner[1], role, option))
    if spec.kind == FITTED:
        return _fitted(spec.key, role)
    if spec.kind == RULE:
        kind = SCRIPTED[spec.key]
        if kind.role != role:
            raise UsageError(option, str(spec), f"{spec.key} plays the {kind.role} seat, not the {role} seat")
        partner = kind(**dict(spec.settings))
        partner.key = str(spec)
        return partner
    if spec.kind in (PERSON, ADAPTIVE_KIND):
        raise UsageError(option, str(spec), "a person or an adaptive agent, not a policy")
    return policy_for(spec.key, role, option)  # a key, a .zip, a module:attr, a proxy:DIR


def fitted_people(directory: Path, name: str = "") -> tuple[str, dict[str, dict]]:
    """The seat and the participants' fits of a directory `tsf humans fit` wrote; a UsageError
    naming `name` (the partner, else the directory) when there is none."""
    path = Path(directory) / STAND_INS
    try:
        fitted = json.loads(path.read_text())
        return fitted["role"], dict(fitted["people"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        problem = f"no stand-ins of `tsf humans fit` in {path} ({error})"
        raise UsageError("--partner" if name else "--partners-from", name or directory, problem) from None


def _fitted(name: str, role: str) -> Partner:
    """`humans:DIR` (a directory of one participant) or `humans:DIR@PARTICIPANT`, written by
    `tsf humans fit`: that participant's fitted human(...), under this name."""
    directory, _, who = name.removeprefix(HUMANS).partition("@")
    role_played, people = fitted_people(Path(directory), name)
    if role_played != role:
        raise UsageError("--partner", name, f"its people played the {role_played} seat, not the {role}")
    who = who or (next(iter(people)) if len(people) == 1 else "")
    if who not in people:
        raise UsageError("--partner", name, "name one participant: humans:DIR@NAME", sorted(people))
    partner = make_partner(people[who]["partner"], role)
    partner.key = name
    return partner


def group_of(name: str) -> str:
    """A partner's group in the population: its outer wrapper, library, a proxy, or outside."""
    spec = SeatSpec.parse(name)
    if spec.kind == PROXY_KIND:
        return "proxy"
    if spec.kind == FITTED:
        return "fitted"
    if spec.kind in ("noisy", "delayed", "sticky", "switch", "human"):
        return {"switch": "switching", "human": "human-like"}.get(spec.kind, spec.kind)
    return "library" if spec.kind == KEY and name in library.registry() else "outside"


# Hand-written partners of each seat: its scripted rule, smaller and larger, slower and faster.
OUTSIDE = {
    "bait": ("circle", ("radius", (80, 150)), ("speed", (1.5, 3))),
    "shooter": ("mirror", ("radius", (220, 280)), ("max_speed", (3, 5))),
}


POPULATION_SKILLS = ("novice", "typical", "practised")


def _person(inner: str, i: int) -> str:
    """The i-th human-like partner of the population: `inner` played at the i-th skill in turn."""
    skill = POPULATION_SKILLS[i % len(POPULATION_SKILLS)]
    return f"human({inner})" if skill == "typical" else f"human({inner},skill={skill})"


def population(role: str) -> dict[str, list[str]]:
    """The default evaluation population of partners of `role`, by group: every library policy,
    its noisy, delayed and sticky stand-ins, switchers between library policies of different
    families, human-like partners (every library policy played by a simulated person, and people
    who drift between the switchers' styles over a session, at the skills of POPULATION_SKILLS in
    turn), and partners outside the library: random,
    and the scripted rule of the seat at its defaults and at four other settings (`OUTSIDE`)."""
    keys = library.keys(role)
    half = len(keys) // 2
    switches = [f"switch({a},{b})" for a, b in zip(keys, keys[half:] + keys[:half], strict=True)]
    rule, (size, sizes), (speed, speeds) = OUTSIDE[role]
    outside = [rule, *(f"{rule}({size}={a},{speed}={b})" for a in sizes for b in speeds), "random"]
    return {
        "library": keys,
        "noisy": [f"noisy({k})" for k in keys],
        "delayed": [f"delayed({k})" for k in keys],
        "sticky": [f"sticky({k})" for k in keys],
        "switching": switches,
        "human-like": [_person(k, i) for i, k in enumerate(keys)]
        + [_person(s[len("switch(") : -1], i) for i, s in enumerate(switches[:half])],
        "outside": outside,
    }
