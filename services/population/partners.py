"""Partners for evaluating an adaptive agent: library policies and stand-ins for humans built from them.

A partner is named by a small grammar, so that an evaluation's partners can be rebuilt by name in
any worker process:

    B5                 a library (or scripted) policy as it is
    noisy(B5)          plays a uniformly random action with probability NOISE per frame (wrappers.py)
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

Partners play in lanes, written once: each wrapper (wrappers.py: noisy, delayed, sticky, switch) works on
arrays of lanes, and a single game is one lane. `Partners` plays the lanes of a batch by name:
partners of one shape (`shape`: the same wrappers with the same settings, nested the same way,
whatever policies they wrap) share one batched form, and the project policies inside (library,
scripted, random) draw from their distributions, each policy asked once a frame for all the
lanes it plays in. So `noisy(switch(B1,B5))` and `noisy(switch(B7,B2))` share one batched form,
and a frame costs one call per policy, not per partner. A human-like partner of project policies
(`human(B5)`, `human(B1,B5)`) plays its own batched form, `HumanLike.act_lanes`. A partner of any
other kind (a plug-in `module:attr`, a human-like hand on a wrapper) is played as it is: one copy
per lane, reset and asked lane by lane.

Every draw, a policy's and each wrapper's, comes from its own stream of `lane_uniforms`, keyed by
the game's seed and the frame: a game's partner depends on its seed, never on which lanes share
the batch. `build` makes the partner of a single game (a stand-in, a recorded
trial): a policy alone plays as itself (its own generator, as every scalar game plays a policy),
and a wrapper plays as one lane of its batched form (`OneGame`), so it gives exactly the actions
its lane gives in any batch.
"""

from __future__ import annotations

import copy
import itertools
import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from services.agent import library
from services.agent.networks import LearnedPolicy
from services.agent.policy import RulePolicy, UniformPolicy
from services.agent.scripted import SCRIPTED
from services.agent.seats import policy_of
from services.population.human_like import STAND_INS, HumanLike
from services.population.seat import (
    HUMANS,
    KEY,
    PROXY_KIND,
    AdaptiveSeat,
    FittedSeat,
    PersonSeat,
    PolicySeat,
    RuleSeat,
    SeatSpec,
    WrapperSeat,
)
from services.population.wrappers import WRAPPERS, Lanes
from services.sim.engine import Game
from services.sim.observation import as_observation, world_values
from services.sim.play import game_seed, policy_seed
from services.sim.sampling import act_lanes, lane_uniforms
from shared.errors import Failure, UsageError
from shared.game import ROLES, checked_action

LANE_WRAPPERS = tuple(name for name, w in WRAPPERS.items() if w.lanes)  # the hand has its own (HumanLike)


@runtime_checkable
class Partner(Protocol):
    """A single game's partner: what it needs of the policy protocol (it acts, it need not report
    probabilities)."""

    key: str
    role: str
    view: str

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs: np.ndarray) -> int: ...


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


class HumanLanes:
    """human_like.HumanLike, whose `act_lanes` is its batched form: every lane gets the actions
    `act` gives the single game of the same seed (reset with that game's seed, `offset` added)."""

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
    """Any other partners, as they are: a copy per lane, reset with the single game's seed
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


class OneGame:
    """A wrapper's batched form in one lane: the partner of a single game. Reset with the seed its
    seat resets a partner with (play.policy_seed of the game's seed) and asked once a frame from
    the game's first, it acts exactly as its lane of that game's seed in any batch."""

    def __init__(self, form: Lanes, key: str, role: str) -> None:
        self.form, self.key, self.role, self.view = form, key, role, form.view
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        game = 0 if seed is None else game_seed(seed, self.role)
        self.form.reset(np.array([game], np.int64))
        self.frame = 0

    def act(self, obs: np.ndarray) -> int:
        action = self.form.act(np.asarray(obs)[None], self.frame)
        self.frame += 1
        return int(action[0])


Leaf = Callable[[SeatSpec], Partner]  # the partner built for one place of a name (a policy, a hand)


def leaves(role: str, option: str = "--partner") -> Leaf:
    """Builds each place of a parsed name once (the same spec object, the same partner): the lanes
    of one name share their policies, as one policy answers for all its lanes."""
    made: dict[int, tuple[SeatSpec, Partner]] = {}

    def leaf(spec: SeatSpec) -> Partner:
        if id(spec) not in made:
            made[id(spec)] = (spec, build(spec, role, option))
        return made[id(spec)][1]

    return leaf


# A policy whose act() draws from its probs() is played from its distributions.
_SAMPLED = (LearnedPolicy.act, RulePolicy.act, UniformPolicy.act)


def _sampled(partner: Partner) -> bool:
    return getattr(type(partner), "act", None) in _SAMPLED


def _lane_wrapper(spec: SeatSpec) -> str:
    """The wrapper `spec` is, where its lanes are a wrapper's batched form ("" otherwise)."""
    return spec.wrapper if isinstance(spec, WrapperSeat) and spec.wrapper in LANE_WRAPPERS else ""


def _setting(spec: WrapperSeat) -> object:
    """What of a wrapper's settings its batched form depends on (delayed(...)'s frames), checked."""
    try:
        return WRAPPERS[spec.wrapper].setting(spec.settings)
    except ValueError as error:
        raise UsageError("--partner", str(spec), str(error)) from None


def shape(spec: SeatSpec, leaf: Leaf) -> tuple:
    """What a partner's batched form depends on: its wrappers, their settings and nesting, and the
    view of the policies inside, not which policies they are."""
    if wrapper := _lane_wrapper(spec):
        setting = _setting(spec)
        return (wrapper, setting, *(shape(inner, leaf) for inner in spec.inner))
    partner = leaf(spec)
    if isinstance(partner, HumanLike) and all(_sampled(p) for p in (partner.first, partner.second) if p):
        return ("human", partner.key)  # one batched form per hand on project policies (HumanLanes)
    return ("policy" if _sampled(partner) else "other", partner.view)


def lanes(specs: list[SeatSpec], leaf: Leaf, stream: int, streams: Iterator[int], offset: int = 0) -> Lanes:
    """The batched form of partners of one `shape`, one spec per lane: their policies draw from
    `stream`, every other draw of the wrappers from the next of `streams` (unique in one form)."""
    kind, first = _lane_wrapper(specs[0]), specs[0]

    def inner(i: int, own: bool = False) -> Lanes:
        inside = [spec.inner[i] for spec in specs]
        if own:  # a stream and a seed offset of its own (a switch's second partner)
            return lanes(inside, leaf, next(streams), streams, offset + 1)
        return lanes(inside, leaf, stream, streams, offset)

    if kind:
        return WRAPPERS[kind].lanes(inner, _setting(first), streams)
    partners = [leaf(spec) for spec in specs]
    played = shape(first, leaf)[0]
    if played == "human":
        return HumanLanes(partners[0], offset)
    if played == "policy":
        return PolicyLanes(partners, stream)
    return EachLane(partners, offset)


def form(specs: list[SeatSpec], role: str, leaf: Leaf) -> Lanes:
    """The batched form of `role`'s partners `specs` (one per lane, all of one shape): its policies
    draw from the seat's stream (batch_play: 0 and 1), its wrappers from 2 on."""
    return lanes(specs, leaf, ROLES.index(role), itertools.count(2))


class Partners:
    """Every lane's partner: the lanes of partners of one shape are played by one batched form,
    the lanes of one partner by the same policies."""

    def __init__(self, specs: list[SeatSpec], role: str, keys: np.ndarray) -> None:
        one = {spec: spec for spec in specs}  # equal specs: one of them, built once (leaves)
        leaf = leaves(role)
        shapes = {spec: shape(spec, leaf) for spec in one.values()}
        self.groups: list[tuple[np.ndarray, Lanes]] = []
        for kind in dict.fromkeys(shapes[one[spec]] for spec in specs):
            rows = np.array([lane for lane, spec in enumerate(specs) if shapes[one[spec]] == kind])
            partner = form([one[specs[lane]] for lane in rows], role, leaf)
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


def make_partner(name: str, role: str) -> Partner:
    """A fresh partner of `role` by name (see the module docstring for the grammar)."""
    return build(SeatSpec.parse(name, "--partner"), role)


def build(spec: SeatSpec, role: str, option: str = "--partner") -> Partner:
    """What plays `role`'s seat in a single game as `spec` says, fresh: a policy, or a partner made
    of policies (a wrapper as one lane of its batched form). A person or an adaptive agent is no
    partner (UsageError): a gateway or the adapter plays them."""
    if _lane_wrapper(spec):
        leaf = leaves(role, option)
        try:
            return OneGame(form([spec], role, leaf), str(spec), role)
        except UsageError:
            raise
        except ValueError as error:  # a switch of partners that read different views
            raise UsageError(option, str(spec), str(error)) from None
    if isinstance(spec, WrapperSeat):  # human(...): the hand of a simulated person
        inner = [build(partner, role, option) for partner in spec.inner]
        try:
            return HumanLike.from_arguments(inner, [f"{name}={value}" for name, value in spec.settings])
        except ValueError as error:
            raise UsageError(option, str(spec), str(error)) from None
    if isinstance(spec, FittedSeat):
        return _fitted(spec.key, role)
    if isinstance(spec, RuleSeat):
        kind = SCRIPTED[spec.key]
        if kind.role != role:
            raise UsageError(option, str(spec), f"{spec.key} plays the {kind.role} seat, not the {role} seat")
        partner = kind(**dict(spec.settings))
        partner.key = str(spec)
        return partner
    if isinstance(spec, PersonSeat | AdaptiveSeat):
        raise UsageError(option, str(spec), "a person or an adaptive agent, not a policy")
    return policy_of(spec.how, spec.key, role, option)  # a key, a .zip, a module:attr, a proxy:DIR


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


def kind_of(name: str) -> str:
    """A partner's kind in the population: its outer wrapper, library, a proxy, fitted or outside.
    (A partner *group*, G1.., is something else: a cluster of partners by what works with them, as
    the grown library names them.)"""
    spec = SeatSpec.parse(name)
    if isinstance(spec, PolicySeat) and spec.how == PROXY_KIND:
        return "proxy"
    if isinstance(spec, FittedSeat):
        return "fitted"
    if isinstance(spec, WrapperSeat):
        return {"switch": "switching", "human": "human-like"}.get(spec.wrapper, spec.wrapper)
    is_key = isinstance(spec, PolicySeat) and spec.how == KEY
    return "library" if is_key and name in library.registry() else "outside"


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
    """The default evaluation population of partners of `role`, by kind (`kind_of`): every library policy,
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
