"""Evaluating the adaptive agent in-process: the games every measurement plays.

`play_games` plays many games of partners (services/adapter/partners.py) with our seat played by
a static library policy or adaptively, as the lanes of one batched engine: the partners in their
batched forms (partners.py), our seat's lanes grouped by the policy they play now, and every
adaptive lane's update batched (`AdapterLanes`, which decides as `Adapter` does). `play_partner`
is the same game on the scalar engine, one at a time, as a live match plays it: the reference the
batched games are checked against, and the calibration's games. Either way the adaptive agent
switches as the agent service does: from the frame after the adapter's choice. Draws differ: a
batched game's come from `lane_uniforms` keyed by its seed (batch_play.py), a scalar game's from
the policies' own generators, so the two agree in distribution, not game for game.

Bulk work runs as jobs of the job system (services/jobs: here, or on workers across machines), each
a batch of consecutive games (`batches`), or one game (the thresholds' scalar games). The
measurements built on it: identification.py (is the partner
identified), team.py (does adapting help), thresholds.py (the out-of-library thresholds) and
results.py (the numbers and summary written out).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import cache, partial
from pathlib import Path

import numpy as np

from services.adapter.core import (
    Adapter,
    AdapterConfig,
    Payoff,
    Scorer,
)
from services.adapter.human_like import SESSION_TRIALS
from services.adapter.partners import Partner, PartnerError, Partners, ask, make_partner
from services.agent import networks
from services.sim.engine import Game
from services.sim.observation import observe, world_values
from services.sim.play import policy_seed, switch_seed
from services.table.table import DEFAULT_TABLE
from shared.game import ROLES, GameConfig, Policy, bait_first, other

LANES = 1024  # games per batch at most


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
    scorer = Scorer([networks.load(k) for k in payoff.partners])
    return Setup(role, payoff, scorer, {k: networks.load(k) for k in payoff.ours})


@dataclass
class Outcome:
    """One game: the team's score, and for an adaptive agent its choices over time."""

    kills_per_minute: float
    switches: int = 0
    guarded: bool = False  # a -guard strategy fell back to the best static policy
    timeline: list[tuple[int, str, str]] = field(default_factory=list)  # (frame, estimate, policy)
    adapter: Adapter | None = field(default=None, repr=False, compare=False)  # its adapter at the end
    values: list[list[float]] = field(default_factory=list)  # the partner's world-view states
    actions: list[int] = field(default_factory=list)  # and actions, when recorded (scalar games)
    scores: np.ndarray | None = None  # (frames, K) the partner's scores, when recorded (batched)
    pairs: np.ndarray | None = None  # (frames, 2) both seats' actions, bait first, when recorded


Agent = str | AdapterConfig  # a static library key of our seat, or an adaptive agent


def play_games(
    games: list[tuple[str, Agent, int]], role: str, config: GameConfig | None = None, record: bool = False
) -> list[Outcome]:
    """Games of (partner name, our agent, seed), our seat `role`, as the lanes of one batch. With
    `record`, each outcome keeps the partner's scores under the library (the Scorer) and both
    seats' actions, frame by frame."""
    from services.sim.batch import BatchGame
    from services.sim.batch_play import RoleLanes

    s, partner_role = setup(role), other(role)
    seeds = np.array([seed for *_, seed in games], np.int64)
    batch = BatchGame(len(games), config, seeds)
    partners = Partners([name for name, *_ in games], partner_role, seeds)
    adaptive: dict[AdapterConfig, list[int]] = {}
    for lane, (_, agent, _) in enumerate(games):
        if isinstance(agent, AdapterConfig):
            adaptive.setdefault(agent, []).append(lane)
    scored = np.arange(len(games)) if record else np.array(sorted(sum(adaptive.values(), [])), np.int64)
    adapters = [
        (np.array(lanes), np.searchsorted(scored, lanes), agent.build_lanes(len(lanes), s.payoff))
        for agent, lanes in adaptive.items()
    ]
    ours = [agent if isinstance(agent, str) else s.payoff.initial(agent) for _, agent, _ in games]
    seat = RoleLanes(role, list(s.ours.values()), [s.payoff.ours.index(k) for k in ours], seeds)
    outcomes = [Outcome(0.0) for _ in games]
    frames = batch.config.frames
    scores = np.zeros((len(scored), frames, len(s.payoff.partners))) if record else None
    pairs = np.zeros((len(games), frames, 2), np.int64) if record else None
    while not batch.done[0]:
        frame = int(batch.state.frame[0])
        observed = cache(partial(observe, batch, partner_role))  # each view once a frame
        try:
            partner_actions = partners.act(observed, frame)
        except PartnerError as error:
            name, _, seed = games[error.lane]
            raise PartnerError(f"partner {name}, seed {seed}: {error.problem}") from None
        our_actions = seat.act(batch)
        if len(scored):
            now = s.scorer.observed({v: observed(v)[scored] for v in s.scorer.views}, partner_actions[scored])
            states = observed("world")[scored]  # what Adapter.update reads: stalls, the guard's kills
            if scores is not None:
                scores[:, frame] = now
        for lanes, rows, adapter in adapters:
            for j in np.flatnonzero(adapter.update(now[rows], states[rows])).tolist():
                seat.choice[lanes[j]] = adapter.policy[j]
                outcomes[lanes[j]].switches += 1
                chosen = (s.payoff.partners[adapter.partner[j]], s.payoff.ours[adapter.policy[j]])
                outcomes[lanes[j]].timeline.append((frame + 1, *chosen))
        pair = bait_first(partner_role, partner_actions, our_actions)
        if pairs is not None:
            pairs[:, frame] = np.stack(pair, axis=1)
        batch.step(*pair)
    for lanes, _, adapter in adapters:
        for lane, guarded in zip(lanes.tolist(), adapter.guarded.tolist(), strict=True):
            outcomes[lane].guarded = guarded
    for lane, kpm in enumerate(batch.kills_per_minute().tolist()):
        outcomes[lane].kills_per_minute = kpm
        if record:
            outcomes[lane].scores, outcomes[lane].pairs = scores[lane], pairs[lane]
    return outcomes


def play_teams(
    teams: list[tuple[str, str]], seeds: list[int], config: GameConfig | None = None, record: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (teams, seeds) kills/min of games of (bait partner, shooter partner) by name, one per
    team and seed, as the lanes of one batch: both seats played by partners (stand-ins, library
    keys, wrappers). With `record`, also the (teams, seeds, frames, 2) actions, bait first, and
    the (teams, seeds, frames + 1) flags of the states in which the fortress has just fired (opened)."""
    from services.sim.batch import BatchGame

    keys = np.array([seed for _ in teams for seed in seeds], np.int64)
    batch = BatchGame(len(keys), config, keys)
    seats = {
        role: Partners([team[i] for team in teams for _ in seeds], role, keys) for i, role in enumerate(ROLES)
    }
    played = np.zeros((len(keys), batch.config.frames, 2), np.int64) if record else None
    opened = np.zeros((len(keys), batch.config.frames + 1), bool)
    while not batch.done[0]:
        frame = int(batch.state.frame[0])
        bait, shooter = (seat.act(cache(partial(observe, batch, r)), frame) for r, seat in seats.items())
        if played is not None:
            played[:, frame] = np.stack([bait, shooter], axis=1)
        batch.step(bait, shooter)
        opened[:, frame + 1] = batch.state.vulnerable == batch.config.vulnerable_frames
    kills = batch.kills_per_minute().reshape(len(teams), len(seeds))
    if played is None:
        return kills
    return kills, played.reshape(len(teams), len(seeds), -1, 2), opened.reshape(len(teams), len(seeds), -1)


def batches(items: list, workers: int, lanes: int = LANES) -> list[list]:
    """Consecutive slices of `items`, of even sizes, to play as batches: at most `lanes` each, and
    at least one per worker. (The fewer the batches, the fewer the calls per game: a frame costs
    about the same whether a policy answers for ten lanes or a hundred.)"""
    count = min(len(items), max(math.ceil(len(items) / lanes), workers))
    bounds = [len(items) * i // count for i in range(count + 1)] if count else [0]
    return [items[a:b] for a, b in itertools.pairwise(bounds)]


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
        try:
            partner_action = ask(partner, observe(game, partner_role, partner.view), game.frame)
        except PartnerError as error:
            raise PartnerError(f"partner {partner.key}, seed {seed}: {error.problem}") from None
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
