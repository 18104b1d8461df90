"""The partner population a library is grown for: generated from a spec, not hand-picked.

A spec (population.toml; `tsf library grow --population FILE`) names, per partner seat, three
families of members, every one able to say how likely it is to take an action (the adapter scores
partners by it):

- `library`: the study's policies of that seat;
- `rule`: a scripted rule over a grid of its settings, each combination one member, named as the
  partner grammar names it (`circle(radius=110,speed=2.5,outside=215)`);
- `events`: policies trained (PPO, or the seat's `events.algorithm`) on a random weighting of the
  game's events (as HSP makes its biased partners: training's EVENT_TERMS), each kept at several
  points of its training (as FCP keeps checkpoints), so that skill varies as well as style.

Each member also plays through the calibrated human-like stand-ins at each skill
(`human(MEMBER,skill=S)`): the stand-in variants. Members are split into training, validation and
test by member, never by seed; the levels of one events run (near copies of each other) and a
member's stand-ins stay on the member's side, so that nothing the test population holds was seen by
training or selection.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.agent.library import FEATURES
from services.agent.networks import HEADS
from services.agent.scripted import SCRIPTED
from services.population.human_like import parse_skill
from shared import config
from shared.game import ROLES

SPEC = Path(__file__).parent / "population.toml"
FAMILIES = ("library", "rule", "events")
SPLITS = ("train", "validation", "test")
RULE_FAMILIES = {"bait": "circle", "shooter": "mirror"}  # the scripted rule of each seat
EVENT_PREFIX = {"bait": "PB", "shooter": "PS"}  # keys of the events members: PB03b, PS10a
# The grown library's keys by seat (GB1.., GS1..); a spec names others (`keys`), so that libraries
# grown from different specs are used side by side (the tuned library's TB1.., TS1..).
KEYS = {"bait": "GB", "shooter": "GS"}
# The keys the growth gives what it trains for a partner group while it is a candidate: a group's
# best response (RB1.., RS1..) and the conditioned teammate (CB, CS); a spec's `keys` may not take them.
RESPONSE_PREFIX = {"bait": "RB", "shooter": "RS"}
CONDITIONED_PREFIX = {"bait": "CB", "shooter": "CS"}
# What an events run or a best response may train with: the policy gradients over the learned heads
# (training/algorithms.py).
GRADIENT_ALGORITHMS = ("PPO", "TRPO", "A2C")
LEVELS = "abcdefgh"  # an events run's levels, in training order
# The event weights' ranges (HSP draws each event's weight at random): kills always pay, deaths
# always cost, and each shaping term is left out (weight 0) or drawn from its range, per frame or
# per event.
KILL, DEATH = (5.0, 30.0), (0.0, 20.0)
SHAPING = {
    "region": 0.1,
    "distance": 0.1,
    "facing": 0.1,
    "speed": 0.1,
    "partner": 0.1,
    "shots": 1.0,
    "shells": 1.0,
}


@dataclass(frozen=True)
class Member:
    """One partner of the population: its name in the partner grammar, its seat and family, and the
    origin it is split by (an events run for its levels, else itself)."""

    name: str
    role: str
    family: str
    origin: str


@dataclass(frozen=True)
class EventsRun:
    """One events-trained partner's recipe: its weights and the levels it is kept at."""

    key: str
    role: str
    weights: dict[str, float]
    steps: int
    levels: tuple[float, ...]
    seed: int
    algorithm: str = "PPO"

    def level_keys(self) -> list[str]:
        return [self.key + LEVELS[i] for i in range(len(self.levels))]


@dataclass(frozen=True)
class Seat:
    """The population of one seat (`role`) and the best response trained for its groups."""

    role: str
    library: tuple[str, ...]
    grid: dict[str, tuple[float, ...]]
    runs: int
    steps: int
    levels: tuple[float, ...]
    learned: tuple[str, ...]
    features: str
    partners: tuple[str, ...]
    response: dict
    algorithm: str = "PPO"  # the events runs'
    warm_start: bool = False  # the best responses imitate their group's best rule before RL (ResponseTable)


@dataclass(frozen=True)
class Spec:
    """A whole population spec (population.toml), checked."""

    seed: int
    games: int
    skills: tuple[str, ...]
    split: dict[str, float]
    groups: dict[str, float]
    selection: dict[str, float]
    seats: dict[str, Seat]
    text_hash: str
    search: Search | None = None  # the growth's search stage (services/growth/search.py)
    keys: dict[str, str] = dataclasses.field(default_factory=lambda: dict(KEYS))  # the grown library's

    def events_runs(self, role: str) -> list[EventsRun]:
        """The seat's events runs, each with its weights drawn from the spec's seed."""
        seat = self.seats[role]
        runs = []
        for i in range(seat.runs):
            rng = np.random.default_rng([self.seed, ROLES.index(role), i])
            weights = {
                "kill": round(float(rng.uniform(*KILL)), 2),
                "death": -round(float(rng.uniform(*DEATH)), 2),
            }
            for term, scale in SHAPING.items():
                if rng.random() < 0.5:
                    weights[term] = round(float(rng.uniform(-scale, scale)), 3)
            key = f"{EVENT_PREFIX[role]}{i + 1:02d}"
            runs.append(
                EventsRun(
                    key,
                    role,
                    weights,
                    seat.steps,
                    seat.levels,
                    self.seed + 100 * ROLES.index(role) + i,
                    seat.algorithm,
                )
            )
        return runs

    def members(self, role: str) -> list[Member]:
        """Every member of the seat's population, the stand-in variants left out."""
        seat = self.seats[role]
        out = [Member(key, role, "library", key) for key in seat.library]
        names, values = list(seat.grid), list(seat.grid.values())
        for combo in itertools.product(*values):
            settings = ",".join(f"{n}={_number(v)}" for n, v in zip(names, combo, strict=True))
            name = f"{RULE_FAMILIES[role]}({settings})"
            out.append(Member(name, role, "rule", name))
        for run in self.events_runs(role):
            out += [Member(key, role, "events", run.key) for key in run.level_keys()]
        return out

    def stand_ins(self, name: str) -> list[str]:
        """A member played through the calibrated stand-ins at each skill."""
        return [f"human({name},skill={skill})" for skill in self.skills]

    def split_of(self, members: list[Member]) -> dict[str, str]:
        """Each member's side (SPLITS), by origin: within each family the origins are ordered by a
        hash of the spec's seed and their name, and cut at the spec's fractions."""
        sides: dict[str, str] = {}
        for family in FAMILIES:
            origins = list(dict.fromkeys(m.origin for m in members if m.family == family))
            origins.sort(key=lambda o: hashlib.sha256(f"{self.seed}:{o}".encode()).hexdigest())
            cuts = np.cumsum([self.split[s] for s in SPLITS]) * len(origins)
            for i, origin in enumerate(origins):
                sides[origin] = SPLITS[min(int(np.searchsorted(cuts, i, side="right")), len(SPLITS) - 1)]
        return {m.name: sides[m.origin] for m in members}


def _number(value: float) -> str:
    return f"{value:g}"


def read(path: Path = SPEC) -> Spec:
    """The spec at `path`, checked whole before anything is grown (every key at every depth, each
    value's kind and range, no grid setting without values): a UsageError naming the file and the key path
    (`--population`)."""
    raw = config.read(SpecFile, path, "--population")
    spec = Spec(
        seed=raw.seed,
        games=raw.games,
        skills=raw.skills,
        split=dataclasses.asdict(raw.split),
        groups=dataclasses.asdict(raw.groups),
        selection=dataclasses.asdict(raw.selection),
        seats={role: getattr(raw, role).seat(role) for role in ROLES},
        text_hash=hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16],
        search=raw.search,
        keys=KEYS | raw.keys,
    )
    return spec


# The spec file's shape, read by shared.config: each table a dataclass that checks its own values.


@dataclass(frozen=True)
class RuleGrid:
    """A seat's `rule`: its scripted rule and the grid of its settings (each combination a member)."""

    family: str
    grid: dict[str, tuple[float, ...]]

    def __post_init__(self) -> None:
        for name, values in self.grid.items():
            if not values or len(set(values)) != len(values):
                raise ValueError(f"grid.{name} = {list(values)}: a list of distinct numbers, at least one")


@dataclass(frozen=True)
class EventsTable:
    """A seat's `events`: how many events-trained partners, how long, with which algorithm (the
    first population's PPO, or the library's TRPO settings, which learn this game about ten times
    faster per sample), kept at which levels."""

    runs: int
    steps: int
    levels: tuple[float, ...]
    learned: tuple[str, ...]
    features: str
    partners: tuple[str, ...]
    algorithm: str = "PPO"

    def __post_init__(self) -> None:
        levels = list(self.levels)
        if (
            not levels
            or len(levels) > len(LEVELS)
            or levels != sorted(levels)
            or not 0 < levels[0] <= levels[-1] <= 1
        ):
            raise ValueError(f"levels = {levels}: increasing fractions in (0, 1], at most {len(LEVELS)}")
        if self.runs < 0 or self.steps < 1:
            raise ValueError(f"runs = {self.runs}, steps = {self.steps}: 0 or more runs of at least 1 step")
        _algorithm(self.algorithm)
        _heads(self.learned)
        _features(self.features)
        if self.runs and not self.partners:
            raise ValueError("partners = []: at least one partner to train with")


@dataclass(frozen=True, kw_only=True)
class ResponseTable:
    """A seat's `response`: the recipe every group's best response is trained as (growth adds the
    key, role, algorithm, seed and partners)."""

    learned: tuple[str, ...]
    features: str
    reward: str
    weights: dict[str, float] = dataclasses.field(default_factory=dict)
    steps: int
    algorithm: str = "PPO"
    warm_start: bool = False

    def __post_init__(self) -> None:
        _algorithm(self.algorithm)
        _heads(self.learned)
        _features(self.features)
        if self.steps < 1 or not self.reward:
            raise ValueError(f"steps = {self.steps}, reward = {self.reward!r}: at least 1 step, a reward")

    def recipe(self) -> dict:
        """The table as registry values (lists, no empty weights), as the file gave it; `warm_start`
        is how it trains, not a registry field (the seat carries it)."""
        values = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}
        return {k: v for k, v in values.items() if (v or k != "weights") and k != "warm_start"}


@dataclass(frozen=True)
class SeatTable:
    """One partner seat's table: its three families and its best response."""

    library: tuple[str, ...]
    rule: RuleGrid
    events: EventsTable
    response: ResponseTable

    def seat(self, role: str) -> Seat:
        events = self.events
        return Seat(
            role=role,
            library=self.library,
            grid=self.rule.grid,
            runs=events.runs,
            steps=events.steps,
            levels=events.levels,
            learned=events.learned,
            features=events.features,
            partners=events.partners,
            response=self.response.recipe(),
            algorithm=events.algorithm,
            warm_start=self.response.warm_start,
        )


@dataclass(frozen=True)
class Split:
    train: float
    validation: float
    test: float

    def __post_init__(self) -> None:
        shares = dataclasses.astuple(self)
        if abs(sum(shares) - 1.0) > 1e-9 or min(shares) <= 0:
            raise ValueError(f"{dataclasses.asdict(self)}: positive fractions that add up to 1")


@dataclass(frozen=True)
class Groups:
    """The partners' groups: at most `most`, the fewest within `regret` of the best; a member whose
    best candidate scores under `floor` kills/min is kept out of them (services/growth/groups.py);
    groups the adapter's filter confuses are merged while it identifies under `identify` of the
    frames and merging costs it at most `regret` (services/growth/library.py)."""

    most: int
    regret: float
    floor: float = 0.0
    identify: float = 0.0  # merge the groups the calibrated filter confuses, up to this share identified

    def __post_init__(self) -> None:
        _bounded(self.most, "regret", self.regret, "group")
        if self.floor < 0 or not 0 <= self.identify <= 1:
            raise ValueError(
                f"floor = {self.floor}, identify = {self.identify}: kills/min, 0 or more; a share from 0 to 1"
            )


@dataclass(frozen=True)
class Selection:
    """The selected members: at most `most`, until the next adds under `gain` of the headroom."""

    most: int
    gain: float

    def __post_init__(self) -> None:
        _bounded(self.most, "gain", self.gain, "member")


def _bounded(most: int, name: str, share: float, counted: str) -> None:
    if most < 1 or share < 0:
        raise ValueError(f"most = {most}, {name} = {share}: at least 1 {counted}, a {name} of 0 or more")


@dataclass(frozen=True)
class Search:
    """The growth's search stage (services/growth/search.py): settings of our seat's rule played in
    all per seat, and seeded games per (partner, setting) pair. A spec without it grows no search."""

    trials: int
    seeds: int = 8
    # Our seat's rule families searched, each its own search (`bait = ["circle", "orbit"]`); a seat
    # not named searches its own rule (RULE_FAMILIES) alone.
    families: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.trials < 1 or self.seeds < 1:
            raise ValueError(f"trials = {self.trials}, seeds = {self.seeds}: at least 1 of each")
        for seat, names in self.families.items():
            rules = [k for k, policy in SCRIPTED.items() if policy.role == seat]
            if seat not in ROLES or not names or not set(names) <= set(rules):
                raise ValueError(
                    f"families.{seat} = {list(names)}: a seat ({', '.join(ROLES)}) and one or more of "
                    f"its rules ({', '.join(rules) or 'none'})"
                )

    def of(self, seat: str) -> tuple[str, ...]:
        """The rule families searched for our seat `seat`."""
        return self.families.get(seat, (RULE_FAMILIES[seat],))


@dataclass(frozen=True)
class SpecFile:
    """A population spec as its file holds it."""

    split: Split
    groups: Groups
    selection: Selection
    bait: SeatTable
    shooter: SeatTable
    seed: int = 0
    games: int = 4
    skills: tuple[str, ...] = ()
    search: Search | None = None
    keys: dict[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        for seat, prefix in self.keys.items():
            taken = {*EVENT_PREFIX.values(), *RESPONSE_PREFIX.values(), *CONDITIONED_PREFIX.values()}
            if seat not in ROLES or not re.fullmatch(r"[A-Z]{2}", prefix) or prefix in taken:
                raise ValueError(
                    f"keys.{seat} = {prefix!r}: a seat ({', '.join(ROLES)}) and two capital letters, "
                    f"not one of {', '.join(sorted(taken))}"
                )
        if len(set((KEYS | self.keys).values())) < len(ROLES):
            raise ValueError(f"keys = {KEYS | self.keys}: a prefix of its own for each seat")
        if self.games < 2 or self.games % 2:
            raise ValueError(f"games = {self.games}: an even number of at least 2 (two halves)")
        for skill in self.skills:
            parse_skill(skill)
        for role in ROLES:  # said with the file, as every other key (shared.config.read)
            family = getattr(self, role).rule.family
            if family != RULE_FAMILIES[role]:
                raise ValueError(
                    f"{role}.rule.family = {family!r}: the {role}'s rule is {RULE_FAMILIES[role]!r}"
                )


def _algorithm(name: str) -> None:
    if name not in GRADIENT_ALGORITHMS:
        raise ValueError(f"algorithm = {name!r}: one of {', '.join(GRADIENT_ALGORITHMS)}")


def _heads(learned: tuple[str, ...]) -> None:
    if not learned or not set(learned) <= set(HEADS):
        raise ValueError(f"learned = {list(learned)}: one or more of {', '.join(HEADS)}")


def _features(features: str) -> None:
    if features not in FEATURES:
        raise ValueError(f"features = {features!r}: one of {', '.join(FEATURES)}")
