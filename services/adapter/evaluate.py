"""Evaluating the adaptive agent in-process: the games every measurement plays.

`play_partner` plays one game of a partner (services/adapter/partners.py) with our seat played by a
static library policy or adaptively. Games are the same core as everywhere (engine, library
policies, the adapter core); the adaptive agent switches as the agent service does: from the frame
after the adapter's choice, with the policy reset by `switch_seed`. Work is spread over processes
(`run_parallel`), each with its own loaded library. The measurements built on it:
identification.py (is the partner identified), team.py (does adapting help), thresholds.py (the
out-of-library thresholds) and results.py (the numbers and summary written out).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from multiprocessing import get_context
from pathlib import Path

from services.adapter.core import (
    Adapter,
    AdapterConfig,
    Payoff,
    Scorer,
)
from services.adapter.human_like import SESSION_TRIALS
from services.adapter.partners import Partner, make_partner
from services.agent import library
from services.sim.engine import Game
from services.sim.observation import observe, world_values
from services.sim.play import policy_seed, switch_seed
from services.table.table import DEFAULT_TABLE
from shared.game import GameConfig, Policy, bait_first, other


@dataclass(frozen=True)
class Setup:
    """What games of one adaptive seat need, loaded once per process."""

    role: str
    payoff: Payoff
    scorer: Scorer
    ours: dict[str, Policy]


@cache
def setup(role: str, table: Path = DEFAULT_TABLE) -> Setup:
    payoff = Payoff.load(role, table)
    scorer = Scorer([library.load(k) for k in payoff.partners])
    return Setup(role, payoff, scorer, {k: library.load(k) for k in payoff.ours})


@dataclass
class Outcome:
    """One game: the team's score, and for an adaptive agent its choices over time."""

    kills_per_minute: float
    switches: int = 0
    guarded: bool = False  # a -guard strategy fell back to the best static policy
    timeline: list[tuple[int, str, str]] = field(default_factory=list)  # (frame, estimate, policy)
    adapter: Adapter | None = field(default=None, repr=False, compare=False)  # its adapter at the end
    values: list[list[float]] = field(default_factory=list)  # the partner's world-view states
    actions: list[int] = field(default_factory=list)  # and actions, when recorded


def play_partner(
    partner: Partner,
    agent: str | AdapterConfig,
    seed: int,
    role: str,
    config: GameConfig | None = None,
    record: bool = False,
    adapter: Adapter | None = None,
) -> Outcome:
    """One game of `partner` with our seat `role` played by a static library key or adaptively
    (by a new adapter, or by `adapter` going on from an earlier game of a session)."""
    s, partner_role = setup(role), other(role)
    game = Game(config, seed)
    partner.reset(policy_seed(seed, partner_role))
    if isinstance(agent, AdapterConfig):
        adapter = adapter or agent.build(s.payoff)
        agent = adapter.policy
    ours = s.ours[agent]
    ours.reset(policy_seed(seed, role))
    outcome = Outcome(0.0)
    while not game.done:
        partner_action = partner.act(observe(game, partner_role, partner.view))
        our_action = ours.act(observe(game, role, ours.view))
        if adapter is not None or record:
            values = world_values(game, partner_role)
        if record:
            outcome.values.append(values)
            outcome.actions.append(partner_action)
        if adapter is not None and adapter.update(s.scorer(values, partner_action), values):
            ours = s.ours[adapter.policy]
            ours.reset(switch_seed(seed, role, game.frame + 1))
            outcome.switches += 1
            outcome.timeline.append((game.frame + 1, adapter.partner, adapter.policy))
        pair = bait_first(partner_role, partner_action, our_action)
        game.step(*pair)
    outcome.kills_per_minute = game.kills_per_minute()
    outcome.guarded = adapter is not None and adapter.guarded
    outcome.adapter = adapter
    return outcome


def play_session(partner: str, agent: AdapterConfig, person: int, role: str) -> list[Outcome]:
    """The trials of one session (human_like.SESSION_TRIALS games, seeds person * trials + i)
    with the same partner; the adapter of each trial is the previous one's `next_trial()`."""
    outcomes: list[Outcome] = []
    for trial in range(SESSION_TRIALS):
        previous = outcomes[-1].adapter.next_trial() if outcomes else None
        seed = person * SESSION_TRIALS + trial
        outcomes.append(play_partner(make_partner(partner, other(role)), agent, seed, role, adapter=previous))
    return outcomes


def run_parallel(
    fn: Callable, tasks: list[tuple], workers: int, progress: Callable[[int, int], None] | None = None
) -> list:
    """fn(*task) for every task, over `workers` processes (in this process when workers <= 1)."""
    results = []
    if workers <= 1:
        for task in tasks:
            results.append(fn(*task))
            if progress:
                progress(len(results), len(tasks))
        return results
    with get_context("fork").Pool(workers) as pool:
        for result in pool.imap(_star, [(fn, task) for task in tasks], chunksize=1):
            results.append(result)
            if progress:
                progress(len(results), len(tasks))
    return results


def _star(job: tuple[Callable, tuple]) -> object:
    fn, task = job
    return fn(*task)
