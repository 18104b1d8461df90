"""The adapter's pure core: which partner type is the partner like, and what should we play.

The partner types are what the adapter chooses by (`Payoff`): the study's library policies of the
partner's role, with the self-play table P (`library`), or the grown library's partner groups
(`groups`: groups.json, each group's members and what each member of ours scores with the group).
Every frame, each type's policies (a library policy; a group's members) score the partner's action
in the state the partner saw (`Scorer`: log pi_k(a_t | s_t), the similarity score of
cem.log_probs). A group's belief is its members' sum, and its estimate is corrected for how it
errs: the choice maximises the expected payoff under how likely each group is the partner's when
the filter estimates a group, as measured on the groups' members each scored as if left out
(`Payoff.trust`). A strategy turns the scores into an estimated partner type C and our policy D
(`AdapterLanes`, for n games at once; one game's `Adapter` is its one-lane view):

- `cem` (the study's): C is the policy with the highest mean log-probability over the last T
  frames (the window, `Window`); D is the best response to C in the self-play table P.
- `bayes`: a hidden Markov model over partner types. The partner switches type with probability
  `hazard` per frame and slips to a uniformly random action with probability `noise`; D maximises
  the expected table entry under the belief instead of trusting the single most likely type.
- `-dwell`: a new D must stay the choice for `dwell` frames before the agent switches to it, so
  that the agent does not flap between policies on noise.
- `-guard`: when the team's realised kills under the adapted policy fall short of what the table
  promised (guard.py), fall back to the best static policy for the rest of the game; and every
  switch doubles the dwell, so switching is bounded.
- `-skill`: the partner's skill is estimated from the same window (skill.py: the holds, key
  changes, lapses and how policy-like the keys are); where the partner is a person of some skill
  with a posterior of at least CONFIDENT, in a window like those the model measured, D maximises
  the skill table's expected entry under the style belief and the skill posterior instead of
  P's; otherwise (a library policy, or not sure) P's choice stands.
- `-memory`: across the trials of a session with the same partner, the adapter goes on from the
  previous trial (`next_trial`): its belief, window, policy and the guard's record carry over, and
  the next trial needs no warm-up. Within one game it is the strategy without it.
- `-ood`: when the best window score is far below what library policies score on their own play
  (calibration.json beside the table, see `calibrate` in thresholds.py), the partner is out of
  library: we play the policy with the best average table entry and say so.

Until `warmup` frames are seen, no estimate is made and the agent plays its initial policy:
`best-average` (the best average table entry) or `random` (drawn from our role's library with
the adapter's seed, as in the study).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np

from services.adapter.cem import evaluation, log_probs, observed_log_probs
from services.adapter.guard import Guard
from services.adapter.skill import CONFIDENT, EVERY, LEVELS, Keys, SkillModel, skill_path
from services.agent import library
from services.agent.policy import end_round_batch
from services.population.adaptive import AdapterConfig
from services.population.partners import build as build_partner
from services.population.seat import SeatSpec
from services.sim import observation as ob
from services.table.table import DEFAULT_TABLE, Table
from shared.config import read as read_config
from shared.errors import UsageError
from shared.game import N_ACTIONS, OBS_SIZE, ROLES, Policy

T = TypeVar("T")
GROUPS = library.NAMED["tuned"] / "groups.json"  # the default agent's partner groups (tsf library grow)


@dataclass(frozen=True)
class Payoff:
    """The table P seen from our seat: values[i, j] = kills/min of partner type i with our policy j.

    The partner types are scored policies (`partners`). Where they are a population's members in
    `groups` (the grown library's, `from_groups`), a member's row is its group's and the estimate
    is the group: `types` names what the adapter identifies, `membership` maps members to them."""

    partners: tuple[str, ...]
    ours: tuple[str, ...]
    values: np.ndarray
    groups: tuple[str, ...] = ()  # the partner groups, where the partners are their members
    group: tuple[int, ...] = ()  # each partner's group
    thresholds: dict[str, float] = field(default_factory=dict)  # out of the groups, by window
    confusion: dict[str, np.ndarray] = field(default_factory=dict)  # the groups' (true, estimated), by window

    @classmethod
    def load(cls, role: str, table: Path = DEFAULT_TABLE) -> Payoff:
        """A table file seen from our seat `role`."""
        return cls.from_table(Table.load(table), role)

    @classmethod
    def from_table(cls, table: Table, role: str) -> Payoff:
        """`role` is our seat."""
        grid = np.array([[table.mean(b, s) for s in table.shooters] for b in table.baits])
        if role == "shooter":
            return cls(tuple(table.baits), tuple(table.shooters), grid)
        return cls(tuple(table.shooters), tuple(table.baits), grid.T)

    @classmethod
    def from_groups(cls, role: str, path: Path | None = None) -> Payoff:
        """The grown library's partner groups seen from our seat `role` (groups.json, which `tsf
        library grow` writes): every member of every group a partner type with its group's row,
        our policies the grown library's members of our seat (by the names they play under)."""
        path = path or groups_path()
        seats = read_config(GroupsFile, path, "groups").seats if path.exists() else {}
        if role not in seats:
            raise UsageError("--partners", "groups", f"no partner groups for the {role} seat in {path}")
        seat = seats[role]
        members = [(m, j) for j, g in enumerate(seat.groups) for m in g.members]
        return cls(
            tuple(m for m, _ in members),
            seat.teammates,
            np.array([seat.groups[j].values for _, j in members], float),
            tuple(g.name for g in seat.groups),
            tuple(j for _, j in members),
            dict(seat.thresholds),
            {t: np.array(c, float) for t, c in seat.confusion.items()},
        )

    @property
    def types(self) -> tuple[str, ...]:
        """What the adapter identifies the partner as: a group, or a library policy."""
        return self.groups or self.partners

    @property
    def membership(self) -> np.ndarray:
        """(K, types): 1 where partner k is of that type (the identity without groups)."""
        if not self.groups:
            return np.eye(len(self.partners))
        return np.eye(len(self.groups))[list(self.group)]

    @property
    def type_values(self) -> np.ndarray:
        """(types, ours): each partner type's row."""
        return self.values[np.argmax(self.membership, axis=0)]

    def trust(self, window: int) -> np.ndarray | None:
        """(estimated, true): how likely each group is the partner's when the filter estimates a
        group, from how it errs on the groups' members each scored as if left out (the confusion
        nearest `window`; `tsf calibrate-adapter --partners groups`); None without one."""
        if not self.confusion:
            return None
        counts = nearest_window(self.confusion, window).T
        seen = counts.sum(axis=1, keepdims=True)
        return np.where(seen > 0, counts / np.where(seen > 0, seen, 1.0), np.eye(len(counts)))

    def best_response(self, partner: int) -> int:
        return int(np.argmax(self.values[partner]))

    def best_average(self) -> int:
        return int(np.argmax(self.values.mean(axis=0)))

    def best_expected(self, belief: np.ndarray) -> int:
        return int(np.argmax(belief @ self.values))

    def initial(self, config: AdapterConfig) -> str:
        """Our policy before the first estimate."""
        if config.initial == "random":
            return random.Random(config.seed).choice(self.ours)
        return self.ours[self.best_average()]


def nearest_window(by_window: dict[str, T], window: int) -> T:
    """What a calibration measured at the window nearest `window` (its keys: windows in frames)."""
    return by_window[min(by_window, key=lambda t: abs(int(t) - window))]


@dataclass(frozen=True)
class Group:
    """One partner group of a groups file: its members and what each of our teammates scores with them."""

    name: str
    members: tuple[str, ...]
    values: tuple[float, ...]
    partners: int = 0

    def __post_init__(self) -> None:
        if not self.members:
            raise ValueError(f"group {self.name}: members = []: at least one member")


@dataclass(frozen=True)
class GroupSeat:
    """The partner groups our seat adapts over: at least one group, a value for every teammate."""

    teammates: tuple[str, ...]
    groups: tuple[Group, ...]
    names: tuple[str, ...] = ()
    thresholds: dict[str, float] = field(default_factory=dict)
    confusion: dict[str, tuple[tuple[float, ...], ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.groups or not self.teammates:
            raise ValueError("groups and teammates: at least one of each")
        for group in self.groups:
            if len(group.values) != len(self.teammates):
                raise ValueError(
                    f"group {group.name}: {len(group.values)} values for {len(self.teammates)} teammates"
                )


@dataclass(frozen=True)
class GroupsFile:
    """A grown library's groups.json (`tsf library grow` writes it), by our seat."""

    seats: dict[str, GroupSeat]
    version: int = 1
    population: str = ""

    def __post_init__(self) -> None:
        for role in self.seats:
            if role not in ROLES:
                raise ValueError(f"seats.{role}: no such seat; valid: {', '.join(ROLES)}")


def groups_path() -> Path:
    """The partner groups in use: those of the last library TSF_LIBRARY names that has them (a
    grown library being made), else the shipped tuned library's (the default agent's)."""
    found = [root / GROUPS.name for root in library.roots() if (root / GROUPS.name).exists()]
    return found[-1] if found else GROUPS


def payoff_of(role: str, partners: str = "library", table: Path = DEFAULT_TABLE) -> Payoff:
    """What an adaptive agent of our seat `role` chooses by: the table P over the study's library
    (`library`), or the grown library's partner groups (`groups`)."""
    return Payoff.from_groups(role) if partners == "groups" else Payoff.load(role, table)


def scorer_of(payoff: Payoff, partner_role: str) -> Scorer:
    """The payoff's partner types as scored policies (library keys, population members, rules),
    each evaluated once here: a compiled rule compiles on its first call (about 0.6 s for the
    rule grid's circles), which must not fall on a match's first frames, when the adapter would
    lag the sim and lose them."""
    scorer = Scorer([build_partner(SeatSpec.parse(k), partner_role) for k in payoff.partners])
    scorer.observed({v: np.zeros((1, OBS_SIZE), np.float32) for v in scorer.views}, np.zeros(1, np.int64))
    return scorer


class Window:
    """Running sums of the last `size` score vectors in each of n lanes: O(K) per frame, never a
    re-scan."""

    def __init__(self, lanes: int, policies: int, size: int) -> None:
        self.size = size
        self.ring = np.zeros((lanes, size, policies))
        self.sums = np.zeros((lanes, policies))
        self.filled, self.next = np.zeros(lanes, np.int64), np.zeros(lanes, np.int64)

    def push(self, lanes: np.ndarray, scores: np.ndarray) -> None:
        """One frame's (len(lanes), K) scores into `lanes` (distinct lane indices)."""
        full = lanes[self.filled[lanes] == self.size]
        self.sums[full] -= self.ring[full, self.next[full]]
        self.filled[lanes[self.filled[lanes] < self.size]] += 1
        self.ring[lanes, self.next[lanes]] = scores
        self.sums[lanes] += scores
        self.next[lanes] = (self.next[lanes] + 1) % self.size

    def means(self) -> np.ndarray:
        """(n, K) means of each lane's window."""
        return self.sums / np.maximum(self.filled, 1)[:, None]


class Scorer:
    """log pi_k(a | s) under every library policy k of one role, from world-view state values."""

    def __init__(self, policies: list[Policy]) -> None:
        self.policies = policies
        self.keys = tuple(p.key for p in policies)
        self.plan = evaluation(policies)  # made once: the stacks of its many members

    def __call__(self, values: list[float] | np.ndarray, action: int) -> np.ndarray:
        """(K,) scores of one frame (a batch of one evaluates exactly as a single observation)."""
        return log_probs(self.policies, [values], [action], self.plan)[0]

    def batch(self, values: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """(n, K) scores of n frames."""
        return log_probs(self.policies, values, actions, self.plan)

    @property
    def views(self) -> set[str]:
        return {p.view for p in self.policies}

    def observed(self, observed: dict[str, np.ndarray], actions: np.ndarray) -> np.ndarray:
        """(n, K) scores of n frames already observed in every view of `views` (the batched
        engine's observations: the same values as `__call__` reads from world values)."""
        return observed_log_probs(self.policies, observed, actions, self.plan)


def ood_threshold(partner_role: str, window: int, path: Path | None = None) -> float:
    """The out-of-library threshold for a window of T frames (the nearest calibrated T), from the
    calibration of the libraries in use; StaleCalibration if it is missing or of other libraries."""
    path = path or library.calibration_path()
    remedy = f"measure it with `tsf calibrate-adapter --out {path}`, or choose a strategy without -ood"
    if not path.exists():
        raise StaleCalibration(f"no out-of-library thresholds at {path}: {remedy}")
    record, now = read_config(Calibration, path, "calibration"), library.manifest_hash()
    if record.library != now:
        raise StaleCalibration(
            f"{path} was measured with library {record.library}, but the library is now {now}: {remedy}"
        )
    if not record.thresholds.get(partner_role):
        raise StaleCalibration(f"{path} has no thresholds for a {partner_role} partner: {remedy}")
    return float(nearest_window(record.thresholds[partner_role], window))


@dataclass(frozen=True)
class Calibration:
    """A library's calibration.json (`tsf calibrate-adapter` writes it): the out-of-library
    thresholds by partner seat and window, and what they were measured with."""

    library: str
    thresholds: dict[str, dict[str, float]]
    quantile: float = 0.01
    margin: float = 0.0
    seeds: tuple[int, ...] = ()
    partners: str = "library"
    self_quantiles: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    confusion: dict[str, dict[str, tuple[tuple[float, ...], ...]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for role, by_window in self.thresholds.items():
            if role not in ROLES or not all(window.isdigit() for window in by_window):
                raise ValueError(
                    f"thresholds.{role}: a table of windows (frames) for a seat of {', '.join(ROLES)}"
                )


class StaleCalibration(ValueError):
    """Out-of-library thresholds missing, or measured with other libraries than the ones loaded."""


class Pairing:
    """Pairs the partner's action for frame f with the state of frame f, whichever arrives first.

    On the bus the two come from different senders, so either may be first. Each frame is paired
    once (a repeated action is ignored), and frames more than `keep` behind the newest are
    forgotten, so a lost message costs one frame and no memory."""

    def __init__(self, keep: int = 90) -> None:
        self.keep = keep
        self.states: dict[int, list[float]] = {}
        self.actions: dict[int, int] = {}
        self.paired: set[int] = set()
        self.newest = -1

    def state(self, frame: int, values: list[float]) -> tuple[list[float], int] | None:
        return self._offer(frame, values, None)

    def action(self, frame: int, action: int) -> tuple[list[float], int] | None:
        return self._offer(frame, None, action)

    def _offer(
        self, frame: int, values: list[float] | None, action: int | None
    ) -> tuple[list[float], int] | None:
        if frame in self.paired or frame <= self.newest - self.keep:
            return None
        if values is not None:
            self.states.setdefault(frame, values)
        if action is not None:
            self.actions.setdefault(frame, action)
        if frame > self.newest:
            self.newest = frame
            self._forget()
        if frame in self.states and frame in self.actions:
            self.paired.add(frame)
            return self.states.pop(frame), self.actions.pop(frame)
        return None

    def _forget(self) -> None:
        oldest = self.newest - self.keep
        for kept in (self.states, self.actions):
            for frame in [f for f in kept if f <= oldest]:
                del kept[frame]
        self.paired = {f for f in self.paired if f > oldest}


def forward(log_belief: np.ndarray, scores: np.ndarray, config: AdapterConfig) -> np.ndarray:
    """The hidden Markov model's forward step in log space, for one lane's (K,) or n lanes' (n, K)
    beliefs and scores: the same operations, element by element, either way."""
    k, h, eta = scores.shape[-1], config.hazard_rate, config.noise
    belief = np.exp(log_belief)
    predicted = (1.0 - h) * belief + h * (1.0 - belief) / max(k - 1, 1)
    likelihood = (1.0 - eta) * np.exp(scores) + eta / N_ACTIONS
    log_post = np.log(predicted) + np.log(likelihood)
    return log_post - np.logaddexp.reduce(log_post, axis=-1, keepdims=True)


class AdapterLanes:
    """Turns the partner's per-frame scores into an estimated type and our policy, in n games at
    once which see their frames together (one game is one lane: `Adapter`). Estimates and policies
    are indices into the payoff's partners and ours."""

    def __init__(
        self,
        config: AdapterConfig,
        payoff: Payoff,
        lanes: int,
        threshold: float | None = None,
        skill: SkillModel | None = None,
    ) -> None:
        if config.strategy_kind.ood and threshold is None:
            raise ValueError(f"strategy {config.strategy} needs an out-of-library threshold")
        if config.strategy_kind.skill and skill is None:
            raise ValueError(f"strategy {config.strategy} needs a skill model")
        self.config, self.payoff, self.threshold, self.skill = config, payoff, threshold, skill
        k = len(payoff.partners)
        self.window = Window(lanes, k, config.window)
        self.frames = 0
        self.log_belief = np.full((lanes, k), -math.log(k))
        self.policy = np.full(lanes, payoff.ours.index(payoff.initial(config)))
        self.membership, self.type_values = payoff.membership, payoff.type_values
        self.trust = payoff.trust(config.window)  # the groups' estimate, corrected for its errors
        self.partner = np.full(lanes, -1)  # the estimated type (payoff.types), -1 until warmup ends
        self.out_of_library = np.zeros(lanes, bool)
        self.candidate, self.held = self.policy.copy(), np.zeros(lanes, np.int64)
        self.fallback = payoff.best_average()  # out of library, or the guard tripped
        self.guard = Guard(self.fallback, lanes) if config.strategy_kind.guard else None
        self.switches = np.zeros(lanes, np.int64)
        self.expected = np.zeros((lanes, len(payoff.ours)))  # the entries the choice maximised
        self.keys = Keys(lanes, config.window) if skill is not None else None
        self.levels = np.zeros((lanes, len(LEVELS)))  # the skill posterior, 0 until estimated
        self.plausible = np.zeros(lanes, bool)  # the window is like a level the model knows

    @property
    def bayes(self) -> bool:
        return self.config.strategy_kind.bayes

    def update(
        self, scores: np.ndarray, values: np.ndarray | None = None, actions: np.ndarray | None = None
    ) -> np.ndarray:
        """Take every lane's scores of one frame, (n, K) log-probabilities in library order, and,
        for the guard, the stalled rounds and the skill estimate, the lanes' world-view states,
        (n, D), and for the skill estimate the partner's actions, (n,); True where a lane's policy
        changes."""
        self.frames += 1
        if self.guard is not None and values is not None:
            self.guard.watch(values)
        if self.keys is not None and values is not None and actions is not None:
            self.keys.push(actions, np.asarray(values)[:, ob.SELF + ob.ALIVE] > 0.5)
        # In a stalled round every library policy plays the same end-round rule (policy.stalled):
        # the frame says nothing about the partner's type, and a partner who does not follow the
        # rule would otherwise look out of library whenever our ship is dead.
        pushed = np.ones(len(scores), bool)
        if values is not None:
            pushed = ~end_round_batch(np.asarray(values, np.float32), "world")[0]
        self._push(np.flatnonzero(pushed), scores)
        if self.frames < self.config.warmup_frames:
            return np.zeros(len(scores), bool)
        means = self.window.means()
        if self.bayes:
            belief = np.exp(self.log_belief)
        else:
            belief = np.eye(len(self.payoff.partners))[np.argmax(means, axis=1)]
        types = belief @ self.membership  # a group's belief: its members'
        self.partner = np.argmax(types, axis=1)
        if self.trust is not None:  # what the estimate says of the partner's true group
            self.expected = types @ self.trust @ self.type_values
        else:
            self.expected = belief @ self.payoff.values
        if self.skill is not None:
            if self.keys.filled and self.frames % EVERY == 0:
                features = self.keys.features(means.max(axis=1))
                self.levels, self.plausible = self.skill.posterior(features, belief)
            person = self.plausible & (self.levels[:, :-1].sum(axis=1) >= CONFIDENT)
            self.expected = np.where(person[:, None], self.skill.expected(belief, self.levels), self.expected)
        choice = np.argmax(self.expected, axis=1)
        if self.threshold is not None:
            self.out_of_library = means.max(axis=1) < self.threshold
        fallback = self.out_of_library.copy()
        if self.guard is not None:  # asked only where not out of library
            fallback |= self.guard.breached(~fallback)
        choice = np.where(fallback, self.fallback, choice)
        switch = self._choose(choice)
        if self.guard is not None and switch.any():
            self._start_guard(np.flatnonzero(switch))
        return switch

    @property
    def guarded(self) -> np.ndarray:
        """Where the guard has fallen back to the best static policy in this game."""
        return self.guard.tripped.copy() if self.guard is not None else np.zeros(len(self.policy), bool)

    def _push(self, lanes: np.ndarray, scores: np.ndarray) -> None:
        """The window and the forward step of the hidden Markov model in `lanes`."""
        self.window.push(lanes, scores[lanes])
        if self.bayes:
            self.log_belief[lanes] = forward(self.log_belief[lanes], scores[lanes], self.config)

    def _choose(self, choice: np.ndarray) -> np.ndarray:
        """A new choice must hold for `dwell` frames before the lane switches to it; under the
        guard every switch doubles the dwell, which bounds a game's switches by about
        log2(frames / dwell) (6 for T = 400)."""
        same = choice == self.policy
        fresh = ~same & (choice != self.candidate)
        self.candidate = np.where(same | fresh, choice, self.candidate)
        self.held = np.where(same | fresh, 0, self.held) + ~same
        dwell = self.config.dwell_frames * (2**self.switches if self.guard is not None else 1)
        switch = ~same & (self.held >= dwell)
        self.policy = np.where(switch, choice, self.policy)
        self.held[switch] = 0
        self.switches += switch
        return switch

    def _start_guard(self, lanes: np.ndarray) -> None:
        """The guard's watch of the lanes that switched, against what the table (P, or the skill
        table) promises the new policy: the entry the choice maximised."""
        self.guard.start(lanes, self.policy[lanes], self.expected[lanes, self.policy[lanes]])

    def next_trial(self) -> AdapterLanes:
        """The adapters for the next trial of sessions with the same partners: these going on
        (`-memory`), or fresh ones."""
        if not self.config.strategy_kind.memory:
            return AdapterLanes(self.config, self.payoff, len(self.policy), self.threshold, self.skill)
        if self.guard is not None:
            self.guard.last = None  # a new game: no kill across the gap
        return self


class Adapter:
    """One game's adapter (the live shell's, a session's): a view of `AdapterLanes` with one lane,
    its estimate and policy named (library keys; "" before the first estimate)."""

    def __init__(self, lanes: AdapterLanes) -> None:
        self.lanes = lanes

    @property
    def config(self) -> AdapterConfig:
        return self.lanes.config

    @property
    def payoff(self) -> Payoff:
        return self.lanes.payoff

    def update(
        self, scores: np.ndarray, values: list[float] | None = None, action: int | None = None
    ) -> bool:
        """Take one frame's (K,) scores and, for the guard and the skill estimate, the frame's
        world-view state values and the partner's action; True when our policy changes."""
        states = None if values is None else np.asarray(values, np.float64)[None]
        actions = None if action is None else np.array([action])
        return bool(self.lanes.update(np.asarray(scores)[None], states, actions)[0])

    @property
    def frames(self) -> int:
        return self.lanes.frames

    @property
    def filled(self) -> int:
        return int(self.lanes.window.filled[0])

    @property
    def policy(self) -> str:
        return self.payoff.ours[self.lanes.policy[0]]

    @property
    def partner(self) -> str:
        estimate = int(self.lanes.partner[0])
        return self.payoff.types[estimate] if estimate >= 0 else ""

    @property
    def out_of_library(self) -> bool:
        return bool(self.lanes.out_of_library[0])

    @property
    def switches(self) -> int:
        return int(self.lanes.switches[0])

    @property
    def guarded(self) -> bool:
        return bool(self.lanes.guarded[0])

    def belief(self) -> np.ndarray:
        """The belief over the partner types (payoff.types): a group's is its members' sum."""
        return np.exp(self.lanes.log_belief[0]) @ self.lanes.membership

    def status(self) -> dict:
        """The adapter's view, as AdapterStatus fields: the scores and belief of each partner type
        (a group's score is its best member's)."""
        c, membership = self.config, self.lanes.membership
        means = self.lanes.window.means()[0]
        scores = np.where(membership > 0, means[:, None], -np.inf).max(axis=0)
        types = self.payoff.types
        return {
            "role": c.role,
            "strategy": c.strategy,
            "window": c.window,
            "filled": self.filled,
            "partner": self.partner,
            "policy": self.policy,
            "scores": dict(zip(types, map(float, scores), strict=True)),
            "belief": dict(zip(types, map(float, self.belief()), strict=True)) if self.lanes.bayes else {},
            "out_of_library": self.out_of_library,
        }

    def next_trial(self) -> Adapter:
        """AdapterLanes.next_trial: this adapter going on (`-memory`), or a fresh one."""
        going_on = self.lanes.next_trial()
        return self if going_on is self.lanes else Adapter(going_on)


# What a config builds, reading the files it names (the table, the calibration, the skill model):
# the config itself is a pure value (services/population/adaptive.py).


def initial_policy(config: AdapterConfig, table: Path = DEFAULT_TABLE) -> str:
    """What our agent plays before the first estimate."""
    return payoff_of(config.role, config.partners, table).initial(config)


def build(config: AdapterConfig, payoff: Payoff | None = None) -> Adapter:
    """The adapter core of one game `config` describes (`payoff`: the shipped table seen
    from our seat)."""
    return Adapter(build_lanes(config, 1, payoff))


def build_lanes(config: AdapterConfig, lanes: int, payoff: Payoff | None = None) -> AdapterLanes:
    """The adapter core of `lanes` games at once (bulk evaluation)."""
    payoff = payoff or payoff_of(config.role, config.partners)
    return AdapterLanes(config, payoff, lanes, threshold(config, payoff), skill_model(config, payoff))


def threshold(config: AdapterConfig, payoff: Payoff | None = None) -> float | None:
    """The out-of-library threshold, for the strategies that have one: the groups' own (measured
    with `tsf calibrate-adapter --partners groups`), or the library's calibration."""
    if not config.strategy_kind.ood:
        return None
    if config.partners == "groups":
        thresholds = (payoff or payoff_of(config.role, "groups")).thresholds
        if not thresholds:
            remedy = f"measure them with `tsf calibrate-adapter --partners groups --out {groups_path()}`"
            raise UsageError("--strategy", config.strategy, f"no out-of-group thresholds: {remedy}")
        return nearest_window(thresholds, config.window)
    try:
        return ood_threshold(config.partner_role, config.window)
    except StaleCalibration as error:
        raise UsageError("--strategy", config.strategy, str(error)) from None


def skill_model(config: AdapterConfig, payoff: Payoff, path: Path | None = None) -> SkillModel | None:
    """The skill model, for the strategies that estimate skill: measured on the libraries in
    use, for our seat, at this window (a UsageError that names the remedy otherwise)."""
    if not config.strategy_kind.skill:
        return None
    path = path or skill_path()
    remedy = (
        f"measure it with `tsf skill-model --table SKILL_TABLE.json --window {config.window} --out {path}`"
        ", or a strategy without -skill"
    )
    try:
        model = SkillModel.load(path)
    except (OSError, ValueError) as error:
        raise UsageError("--strategy", config.strategy, f"no skill model ({error}): {remedy}") from None
    found = {
        "library": (model.library, library.manifest_hash()),
        "seat": (model.role, config.role),
        "partners": (model.styles, payoff.partners),
        "teammates": (model.teammates, payoff.ours),
        "window": (model.window, config.window),
    }
    if differ := [f"{k} {was}, not {now}" for k, (was, now) in found.items() if was != now]:
        raise UsageError(
            "--strategy", config.strategy, f"{path} was measured for {'; '.join(differ)}: {remedy}"
        )
    return model
