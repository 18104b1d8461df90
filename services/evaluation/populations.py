"""Partner populations by name, as Melting Pot names its scenarios: each a frozen value that an
evaluation plan carries and every result records (`Population.name`).

- `default`: the population of the partners' seat (services/population/partners.py: every
  library policy, its noisy, delayed and sticky stand-ins, switchers, human-like partners and
  partners outside the library), broken down by kind (`kind_of`: library, noisy, ...).
- `held-out`: the shipped grown library's test split (held_out.py: partners its growth never saw,
  members and their stand-ins), broken down by partner group (G1..), and by members and stand-ins.
- a grown library's directory (one `tsf library grow` wrote, with its run's records): its test
  split, as `held-out` is the shipped one's.
- a user's list (`tsf eval --partner`, `--partners-from`): those partners, broken down by kind.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from services.evaluation import held_out
from services.population.partners import kind_of, population
from shared.errors import UsageError

DEFAULT = "default"
HELD_OUT = "held-out"
NAMES = (DEFAULT, HELD_OUT)  # and a grown library's directory
LISTED = "listed"  # a user's list of partners


@dataclass(frozen=True)
class Population:
    """Partners of one seat, by name; `run`, where they are a grown library's test split, names
    that library (its run's records give each partner's group)."""

    name: str
    role: str  # the partners' seat
    partners: tuple[str, ...]
    run: Path | None = None

    @property
    def parts(self) -> str:
        """What the results are broken down by: partner groups (a test split) or kinds."""
        return "group" if self.run else "kind"

    def part_of(self, partner: str) -> str:
        """A partner's group (G1..; "other" where the run placed it in none) or its kind."""
        if self.run is None:
            return kind_of(partner)
        return held_out.test_partners(self.role, self.run).get(partner, "other")

    @property
    def subsets(self) -> dict[str, Callable[[str], bool]]:
        """The parts each result is also given for: a test split's members and stand-ins."""
        return held_out.PARTS if self.run else {}

    @property
    def members(self) -> dict[str, str] | None:
        """A test split's members with their groups: what identification is measured on."""
        return held_out.members(self.role, self.run) if self.run else None


def default(role: str) -> Population:
    """The default population of partners of seat `role`."""
    return Population(DEFAULT, role, tuple(p for kind in population(role).values() for p in kind))


def split_of(role: str, run: Path = held_out.RUN, name: str = HELD_OUT) -> Population:
    """A grown library's test split of seat `role` (the shipped grown library's: `held-out`)."""
    return Population(name, role, tuple(held_out.test_partners(role, run)), run)


def listed(partners: list[str] | tuple[str, ...], role: str, name: str = LISTED) -> Population:
    """A user's list of partners of seat `role`."""
    return Population(name, role, tuple(partners))


def named(name: str, role: str, option: str = "--population") -> Population:
    """The population `name` names for partners of seat `role`: `default`, `held-out`, or a grown
    library's directory (its test split); anything else is a UsageError about `option`."""
    if name == DEFAULT:
        return default(role)
    if name == HELD_OUT:
        return split_of(role)
    run = Path(name)
    if (run / "run-population.json").is_file() and (run / "run-summary.json").is_file():
        return split_of(role, run, name)
    raise UsageError(option, name, "not a population", [*NAMES, "a grown library's directory"])
