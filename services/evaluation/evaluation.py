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
from services.evaluation import figures, held_out, identification, results, team
from services.evaluation.results import TeamGame
from services.jobs.kinds import Progress, Runner, in_process
from services.population.adaptive import STRATEGIES, AdapterConfig
from services.population.partners import SWITCH_AT, check_partner, population
from shared.errors import UsageError
from shared.game import FPS, other

KINDS = team.KINDS | identification.KINDS  # the job kinds an evaluation hands out
HERE = in_process(KINDS)  # the runner that plays them in this process


@dataclass(frozen=True)
class EvalPlan:
    """One evaluation, whole: what `tsf eval` asks for. Every partner is built and asked once when
    the plan is made (before any worker starts)."""

    role: str = "shooter"  # the adaptive agent's seat; the partners play the other
    partners: tuple[str, ...] = ()  # by name; none given: the population of the other seat
    seeds: int = 5  # seeded one-minute games per partner and agent (people, with `sessions`)
    windows: tuple[int, ...] = (150, 400, 800)  # the study's CEM agent at each
    strategies: tuple[str, ...] = ()  # each compared at `strategy_window`; none: all the seat has
    strategy_window: int = AdapterConfig.window
    identify_seeds: int = 3  # games per library partner for identification
    identify: bool = True
    performance: bool = True
    sessions: bool = False  # team games as sessions of three trials with the same partner
    job_games: int | None = None  # games of one job (None: each measurement's default)
    # The partner population's test split instead (held_out.py): its members and stand-ins, the
    # static policies of both libraries, the grown library's adaptive agent and the study's, and
    # identification of the test members' groups.
    held_out: bool = False

    def __post_init__(self) -> None:
        if self.held_out and not self.partners:
            object.__setattr__(self, "partners", tuple(held_out.test_partners(self.partner_role)))
        if not self.partners:
            everyone = tuple(p for group in population(self.partner_role).values() for p in group)
            object.__setattr__(self, "partners", everyone)
        for name in dict.fromkeys(self.partners):
            check_partner(name, self.partner_role)
        if not self.strategies:  # a -skill strategy only where a skill model fits seat and window
            object.__setattr__(self, "strategies", tuple(s for s in STRATEGIES if self._has_model(s)))
        for strategy in self.strategies:  # a model asked for and missing: one line, before any worker
            self._has_model(strategy, say=True)

    def _has_model(self, strategy: str, say: bool = False) -> bool:
        """Whether the strategy has what it needs at this seat and window (a -skill strategy its
        skill model); with `say`, the UsageError that says what is missing instead of False."""
        if "skill" not in strategy:
            return True
        config = AdapterConfig(self.role, self.strategy_window, strategy)
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
    def agents(self) -> list[str]:
        """Every static policy of our seat, then the adaptive variants (held out: the grown
        library's members too, and the two shipped adaptive agents at `strategy_window`)."""
        if self.held_out:
            shipped = [
                AdapterConfig(self.role, self.strategy_window, partners=p).name for p in ("groups", "library")
            ]
            return held_out.statics(self.role) + shipped
        variants = team.variants(list(self.windows), list(self.strategies), self.strategy_window)
        return library.keys(self.role) + variants


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
    comparison: dict | None
    curves: Curves | None

    def write(self, out: Path) -> Path:
        """The numbers (JSON, CSV), the figures and summary.md into `out`; the summary's path."""
        summary = results.write_results(out, self.identification, self.games, self.comparison)
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
    per_partner.csv, the figure and summary.md into `out` (no identification); the summary's path."""
    played = results.read_games(games)
    nothing = EvalPlan(role, identify=False, performance=False)
    return EvalReport(nothing, None, played, team.compare(played), None).write(out)


def evaluate(
    plan: EvalPlan, run: Runner = HERE, progress: Callable[[str], Progress] | None = None
) -> EvalReport:
    """Play and measure what `plan` asks, with the games as jobs run by `run` (here, or on the job
    system's workers); `progress(step)` gives the (done, total) callback of each step."""
    shown = progress or (lambda step: None)
    ident, games, comparison, curves = None, [], None, None
    if plan.identify and plan.held_out:
        seeds = list(range(plan.identify_seeds))
        members = held_out.members(plan.partner_role)
        ident = identification.identification(
            plan.role, list(plan.windows), seeds, run, shown("identification"), plan.job_games, members
        )
    elif plan.identify:
        seeds = list(range(plan.identify_seeds))
        ident = identification.identification(
            plan.role, list(plan.windows), seeds, run, shown("identification"), plan.job_games
        )
        keys = library.keys(plan.partner_role)
        first, second = keys[0], keys[len(keys) // 2]
        curves = Curves(first, second, identification.switch_scores(first, second, 0, plan.role))
    if plan.performance:
        partners, agents, seeds = list(plan.partners), plan.agents, list(range(plan.seeds))
        if plan.sessions:
            games = team.sessions(plan.role, partners, agents, seeds, run, shown("team games"))
        else:
            games = team.team(plan.role, partners, agents, seeds, run, shown("team games"), plan.job_games)
        if plan.held_out:
            groups = held_out.group_of(plan.role)
            comparison = team.compare(games, lambda p: groups.get(p, "other"), held_out.KINDS)
        else:
            comparison = team.compare(games)
    return EvalReport(plan, ident, games, comparison, curves)
