"""The partner population a library is grown for: generated from a spec, not hand-picked.

A spec (population.toml; `tsf library grow --population FILE`) names, per partner seat, three
families of members, every one able to say how likely it is to take an action (the adapter scores
partners by it):

- `library`: the study's policies of that seat;
- `rule`: a scripted rule over a grid of its settings, each combination one member, named as the
  partner grammar names it (`circle(radius=110,speed=2.5,outside=215)`);
- `events`: PPO policies trained on a random weighting of the game's events (as HSP makes its
  biased partners: training's EVENT_TERMS), each kept at several points of its training (as FCP
  keeps checkpoints), so that skill varies as well as style.

Each member also plays through the calibrated human-like stand-ins at each skill
(`human(MEMBER,skill=S)`): the stand-in variants. Members are split into training, validation and
test by member, never by seed; the levels of one events run (near copies of each other) and a
member's stand-ins stay on the member's side, so that nothing the test population holds was seen by
training or selection.
"""

from __future__ import annotations

import hashlib
import itertools
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.population.human_like import parse_skill
from shared.errors import UsageError
from shared.game import ROLES

SPEC = Path(__file__).parent / "population.toml"
FAMILIES = ("library", "rule", "events")
SPLITS = ("train", "validation", "test")
RULE_FAMILIES = {"bait": "circle", "shooter": "mirror"}  # the scripted rule of each seat
EVENT_PREFIX = {"bait": "PB", "shooter": "PS"}  # keys of the events members: PB03b, PS10a
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
                    key, role, weights, seat.steps, seat.levels, self.seed + 100 * ROLES.index(role) + i
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
    """The spec at `path`, checked: a UsageError naming the first wrong key or value (`--population`)."""
    try:
        text = Path(path).read_bytes()
        raw = tomllib.loads(text.decode())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
        raise UsageError("--population", path, f"cannot be read as TOML ({error})") from None
    top = {"seed", "games", "skills", "split", "groups", "selection", *ROLES}
    _known(raw, top, path, "")
    try:
        seats = {role: _seat(role, raw[role], path) for role in ROLES}
        spec = Spec(
            seed=int(raw.get("seed", 0)),
            games=int(raw.get("games", 4)),
            skills=tuple(raw.get("skills", ())),
            split={s: float(raw["split"][s]) for s in SPLITS},
            groups={"most": int(raw["groups"]["most"]), "regret": float(raw["groups"]["regret"])},
            selection={"most": int(raw["selection"]["most"]), "gain": float(raw["selection"]["gain"])},
            seats=seats,
            text_hash=hashlib.sha256(text).hexdigest()[:16],
        )
    except KeyError as missing:
        raise UsageError("--population", path, f"lacks {missing.args[0]!r}") from None
    except (TypeError, ValueError) as error:
        raise UsageError("--population", path, str(error)) from None
    if spec.games < 2 or spec.games % 2:
        raise UsageError(
            "--population", path, f"games = {spec.games}: an even number of at least 2 (two halves)"
        )
    if abs(sum(spec.split.values()) - 1.0) > 1e-9 or min(spec.split.values()) <= 0:
        raise UsageError("--population", path, f"split = {spec.split}: positive fractions that add up to 1")
    for skill in spec.skills:
        try:
            parse_skill(skill)
        except ValueError as error:
            raise UsageError("--population", path, str(error)) from None
    return spec


def _known(raw: dict, keys: set[str], path: Path, where: str) -> None:
    for key in raw:
        if key not in keys:
            raise UsageError("--population", path, f"unknown key {where}{key}", sorted(keys))


def _seat(role: str, raw: dict, path: Path) -> Seat:
    _known(raw, {"library", "rule", "events", "response"}, path, f"{role}.")
    rule, events, response = raw["rule"], raw["events"], raw["response"]
    if rule["family"] != RULE_FAMILIES[role]:
        raise ValueError(
            f"{role}.rule.family = {rule['family']!r}: the {role}'s rule is {RULE_FAMILIES[role]!r}"
        )
    _known(events, {"runs", "steps", "levels", "learned", "features", "partners"}, path, f"{role}.events.")
    levels = tuple(float(x) for x in events["levels"])
    if (
        not levels
        or len(levels) > len(LEVELS)
        or list(levels) != sorted(levels)
        or not 0 < levels[0] <= levels[-1] <= 1
    ):
        raise ValueError(
            f"{role}.events.levels = {list(levels)}: increasing fractions in (0, 1], at most {len(LEVELS)}"
        )
    return Seat(
        role=role,
        library=tuple(raw["library"]),
        grid={name: tuple(float(v) for v in values) for name, values in rule["grid"].items()},
        runs=int(events["runs"]),
        steps=int(events["steps"]),
        levels=levels,
        learned=tuple(events["learned"]),
        features=str(events["features"]),
        partners=tuple(events["partners"]),
        response=dict(response),
    )
