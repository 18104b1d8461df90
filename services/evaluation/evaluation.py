"""The evaluation of the adaptive agent as one function: `evaluate(EvalPlan) -> EvalReport` puts
its steps in order (identification of library partners, team games of every partner with every
agent, the comparison with the best static policy, the log-probability curves of one switching
partner), and `EvalReport.write` writes the numbers, figures and summary. `tsf eval` turns its
options into a plan and prints; bench/eval.py calls `evaluate` in-process."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.adapter import core
from services.adapter.core import Payoff
from services.agent import library
from services.evaluation import figures, held_out, identification, populations, results, team
from services.evaluation.populations import Population
from services.evaluation.results import Comparison, TeamGame
from services.jobs.kinds import Progress, Runner, in_process
from services.population.adaptive import STRATEGIES, AdapterConfig
from services.population.partners import check_partner
from services.population.wrappers import SWITCH_AT
from shared.errors import UsageError
from shared.game import FPS, other

KINDS = team.KINDS | identification.KINDS  # the job kinds an evaluation hands out
HERE = in_process(KINDS)  # the runner that plays them in this process


@dataclass(frozen=True)
class EvalPlan:
    """One evaluation, whole: what `tsf eval` asks for. Every partner is built and asked once when
    the plan is made (before any worker starts).

    The agents compared are, by default, what ships: the static policies of every shipped library
    (the study's and the grown library's members) and the shipped default adaptive agent (over the
    grown library's partner groups) with the study's, at `strategy_window`; the population is what
    the user chooses. With `variants`, the study's adaptive variants instead (its CEM agent at each
    window, each strategy at `strategy_window`) against the study's static policies."""

    role: str = "shooter"  # the adaptive agent's seat; the partners play the other
    population: Population | None = None  # by name (populations.py); None: the default population
    seeds: int = 5  # seeded one-minute games per partner and agent (people, with `sessions`)
    windows: tuple[int, ...] = (150, 400, 800)  # identification's windows; the CEM agent's (`variants`)
    strategies: tuple[str, ...] = ()  # `variants`: each compared at `strategy_window`; none: all the seat has
    strategy_window: int = AdapterConfig.window
    identify_seeds: int = 3  # games per library partner for identification
    identify: bool = True
    performance: bool = True
    sessions: bool = False  # team games as sessions of three trials with the same partner
    job_games: int | None = None  # games of one job (None: each measurement's default)
    variants: bool = False  # the study's adaptive variants, not the shipped agents

    def __post_init__(self) -> None:
        if self.population is None:
            object.__setattr__(self, "population", populations.default(self.partner_role))
        if self.population.role != self.partner_role:
            raise UsageError("--role", self.role, f"the population {self.population.name} plays it")
        for name in dict.fromkeys(self.population.partners):
            check_partner(name, self.partner_role)
        if self.strategies and not self.variants:
            object.__setattr__(self, "variants", True)
        if self.variants and not self.strategies:  # a -skill strategy only where a skill model fits
            object.__setattr__(self, "strategies", tuple(s for s in STRATEGIES if self._has_model(s)))
        for strategy in self.strategies:  # a model asked for and missing: one line, before any worker
            self._has_model(strategy, say=True)

    def _has_model(self, strategy: str, say: bool = False) -> bool:
        """Whether the strategy has what it needs at this seat and window (a -skill strategy its
        skill model); with `say`, the UsageError that says what is missing instead of False."""
        config = AdapterConfig(self.role, self.strategy_window, strategy)
        if not config.strategy_kind.skill:
            return True
        try:
            core.skill_model(config, Payoff.load(self.role))
        except UsageError:
            if say:
                raise
            return False
        return True

    @property
    def partner_role(self) -> str:
        return other(self.role)

    @property
    def partners(self) -> tuple[str, ...]:
        return self.population.partners

    @property
    def agents(self) -> list[str]:
        """Every static policy of our seat, then the adaptive agents (`variants`: the study's)."""
        if self.variants:
            variants = team.variants(list(self.windows), list(self.strategies), self.strategy_window)
            return library.keys(self.role) + variants
        study = AdapterConfig(self.role, self.strategy_window, partners="library")
        shipped = [AdapterConfig.shipped(self.role, self.strategy_window).name, study.name]
        return held_out.statics(self.role) + shipped


@dataclass(frozen=True)
class Curves:
    """The similarity scores of one game with a partner that switches type (the figure's)."""

    first: str
    second: str
    scores: np.ndarray = field(repr=False)  # (frames, K) under the partner's library


@dataclass(frozen=True)
class EvalReport:
    """What an evaluation measured: identification.json's and comparison.json's documents (what
    the figures draw, from here or read back), every team game, and the switching partner's curves."""

    plan: EvalPlan
    identification: dict | None
    games: list[TeamGame]
    comparison: Comparison | None
    curves: Curves | None

    def write(self, out: Path) -> Path:
        """The numbers (JSON, CSV), the figures and summary.md into `out`; the summary's path."""
        name = self.plan.population.name
        summary = results.write_results(out, self.identification, self.games, self.comparison, name)
        if self.identification:
            figures.accuracy_vs_window(self.identification, out / "identification.png")
        if self.curves:
            c, keys = self.curves, library.keys(self.plan.partner_role)
            title = f"Partner noisy(switch({c.first},{c.second})), switching at {SWITCH_AT / FPS:.0f} s"
            figures.logprob_curves(
                c.scores, keys, min(self.plan.windows), title, out / "logprob_curves.png", SWITCH_AT
            )
        if self.comparison:
            figures.adaptive_vs_static(self.comparison, out / "adaptive_vs_static.png")
        return summary


def reanalyse(games: Path, role: str, out: Path) -> Path:
    """An evaluation's team games (its team.csv) analysed again, not played: the comparison,
    per_partner.csv, the figure and summary.md into `out` (no identification); the summary's path.
    The games' population is the one their team.csv names (else a list of their partners)."""
    played = results.read_games(games)
    partners = tuple(dict.fromkeys(g.partner for g in played))
    name = results.population_of(games)
    population = (
        populations.named(name, other(role))
        if name in populations.NAMES or (name and Path(name).is_dir())
        else populations.listed(partners, other(role), name or populations.LISTED)
    )
    nothing = EvalPlan(role, population, identify=False, performance=False)
    return EvalReport(nothing, None, played, team.compare(played, population), None).write(out)


def _identify(plan: EvalPlan, run: Runner, shown: Callable[[str], Progress]) -> tuple[dict, Curves | None]:
    """Identification: of the test members' partner groups (a test split), else of the library's
    partners, with the curves of one switching partner."""
    seeds = list(range(plan.identify_seeds))
    windows = list(plan.windows)
    if members := plan.population.members:
        found = identification.identification(
            plan.role, windows, seeds, run, shown("identification"), plan.job_games, members
        )
        return found, None
    found = identification.identification(
        plan.role, windows, seeds, run, shown("identification"), plan.job_games
    )
    keys = library.keys(plan.partner_role)
    first, second = keys[0], keys[len(keys) // 2]
    return found, Curves(first, second, identification.switch_scores(first, second, 0, plan.role))


def evaluate(
    plan: EvalPlan, run: Runner = HERE, progress: Callable[[str], Progress] | None = None
) -> EvalReport:
    """Play and measure what `plan` asks, with the games as jobs run by `run` (here, or on the job
    system's workers); `progress(step)` gives the (done, total) callback of each step."""
    shown = progress or (lambda step: None)
    ident, games, comparison, curves = None, [], None, None
    if plan.identify:
        ident, curves = _identify(plan, run, shown)
    if plan.performance:
        partners, agents, seeds = list(plan.partners), plan.agents, list(range(plan.seeds))
        if plan.sessions:
            games = team.sessions(plan.role, partners, agents, seeds, run, shown("team games"))
        else:
            games = team.team(plan.role, partners, agents, seeds, run, shown("team games"), plan.job_games)
        comparison = team.compare(games, plan.population)
    return EvalReport(plan, ident, games, comparison, curves)
