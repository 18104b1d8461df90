"""Evaluating the adaptive agent in-process: the games every measurement plays.

`play_games` plays games of partners (services/population/partners.py) with our seat played by a
static library policy or adaptively, as the lanes of one batched engine (one game is one lane):
the partners in their batched forms (partners.py), our seat's lanes grouped by the policy
they play now, and every adaptive lane's update batched (`AdapterLanes`). The adaptive agent
switches as the live one does: the adapter scores every frame and rules on every SCORE_FRAMES-th
(shared.game.scoring), and its choice then plays from the next frame. A game's draws come
from `lane_uniforms` keyed by its seed (batch_play.py), so a game is the same whichever batch it
is played in. `play_session` plays a session's trials one after the other, an adapter carried
from trial to trial.

Bulk work runs as jobs of the job system (services/jobs: here, or on workers across machines), each
a batch of consecutive games (`batches`), or one game or session. The measurements built on it:
identification.py (is the partner identified), team.py (does adapting help), thresholds.py (the
out-of-library thresholds) and results.py (the numbers and summary written out).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from services.adapter import core
from services.adapter.core import AdapterLanes, Payoff, Scorer
from services.population.adaptive import AdapterConfig
from services.population.human_like import SESSION_TRIALS
from services.population.partners import PartnerError, Partners, build
from services.population.seat import SeatSpec
from services.table.table import DEFAULT_TABLE
from shared.game import OBS_SIZE, ROLES, GameConfig, Policy, bait_first, other, scoring

LANES = 1024  # games per batch at most


@dataclass(frozen=True)
class Setup:
    """What games of one adaptive seat need, loaded once per process: what it chooses by (the
    table P over the study's library, or the grown library's partner groups) and the partner
    types' scorer."""

    role: str
    payoff: Payoff
    scorer: Scorer


@cache
def setup(role: str, partners: str = "library", table: Path = DEFAULT_TABLE) -> Setup:
    payoff = core.payoff_of(role, partners, table)
    return Setup(role, payoff, core.scorer_of(payoff, other(role)))


@cache
def policy(name: str, role: str) -> Policy:
    """A static policy of our seat by the name it plays under (a key, a rule with its settings),
    loaded once per process: every lane that plays it shares it, as a batch's policies do."""
    return build(SeatSpec.parse(name, "--agent"), role)


@dataclass
class Outcome:
    """One game: the team's score, and for an adaptive agent its choices over time."""

    kills_per_minute: float
    switches: int = 0
    guarded: bool = False  # a -guard strategy fell back to the best static policy
    timeline: list[tuple[int, str, str]] = field(default_factory=list)  # (frame, estimate, policy)
    values: np.ndarray | None = None  # (frames, D) the partner's world-view states, when recorded
    actions: np.ndarray | None = None  # (frames,) and its actions
    pairs: np.ndarray | None = None  # (frames, 2) both seats' actions, bait first
    scores: np.ndarray | None = None  # (frames, K) the partner's scores under the library, when scored


def _our_lanes(
    games: list[tuple[SeatSpec, SeatSpec, int]], role: str, adapters: dict[AdapterConfig, AdapterLanes] | None
) -> tuple[dict[str, int], list[tuple], list[int]]:
    """Our seat in a batch of `play_games`: every policy it plays, by name (its index), the
    adaptive agents' lanes (lanes, the adapter, its payoff's policies' indices, its scorer), and
    each lane's first policy (an adaptive lane's initial one, or where a session's adapter left off)."""
    configs = [agent.adaptive(role) for _, agent, _ in games]
    adaptive: dict[AdapterConfig, list[int]] = {}
    for lane, config in enumerate(configs):
        if config is not None:
            adaptive.setdefault(config, []).append(lane)
    played: dict[str, int] = {}  # every policy our seat plays in the batch, by name: its index
    for (_, agent, _), config in zip(games, configs, strict=True):
        names = setup(role, config.partners).payoff.ours if config else (str(agent),)
        for name in names:
            played.setdefault(name, len(played))
    groups = []  # (lanes, the adapter, its payoff's policies' indices among `played`, its scorer)
    for agent, lanes in adaptive.items():
        s = setup(role, agent.partners)
        adapter = (adapters or {}).get(agent) or core.build_lanes(agent, len(lanes), s.payoff)
        groups.append((np.array(lanes), adapter, np.array([played[n] for n in s.payoff.ours]), s.scorer))
    ours = [-1 if c else played[str(a)] for (_, a, _), c in zip(games, configs, strict=True)]
    for lanes, adapter, index, _ in groups:
        for lane, chosen in zip(lanes.tolist(), index[adapter.policy].tolist(), strict=True):
            ours[lane] = chosen
    return played, groups, ours


def play_games(
    games: list[tuple[SeatSpec, SeatSpec, int]],
    role: str,
    config: GameConfig | None = None,
    record: bool = False,
    adapters: dict[AdapterConfig, AdapterLanes] | None = None,
    score: str = "",
) -> list[Outcome]:
    """Games of (partner, our agent, seed), our seat `role`, as the lanes of one batch: our agent is
    a static library policy of our seat or the adaptive agent (`SeatSpec.adaptive`). An
    adaptive agent's games go on with its adapter in `adapters` (a session's next trial; one lane
    per game of that agent, in order), else with a new one. With `record`, each outcome keeps the
    partner's states and actions and both seats' actions, frame by frame; with `score` ("library"
    or "groups"), the partner's scores under those partner types (their Scorer), frame by frame."""
    from services.sim.batch import BatchGame
    from services.sim.batch_play import RoleLanes, play_lanes

    partner_role = other(role)
    seeds = np.array([seed for *_, seed in games], np.int64)
    batch = BatchGame(len(games), config, seeds)
    partners = Partners([partner for partner, *_ in games], partner_role, seeds)
    played, groups, ours = _our_lanes(games, role, adapters)
    seat = RoleLanes(role, [policy(n, role) for n in played], ours, seeds)
    scored_by = setup(role, score).scorer if score else None
    outcomes = [Outcome(0.0) for _ in games]
    frames = batch.config.frames
    seen: list[np.ndarray] = []  # the partner's states, frame by frame (record)
    scores = np.zeros((len(games), frames, len(scored_by.policies))) if score else None
    pairs = np.zeros((len(games), frames, 2), np.int64) if record else None
    partner_seat = ROLES.index(partner_role)

    def each_frame(frame: int, seen_by: list, actions: list[np.ndarray]) -> None:
        """The adaptive lanes' updates (a switch plays from the frame after its scoring frame, as
        the live adapter's ruling does: shared.game.ruled_at) and what is recorded."""
        observed, partner_actions = seen_by[partner_seat], actions[partner_seat]
        if groups:
            states = observed("world")  # what AdapterLanes.update reads: stalls, the guard's kills
        for lanes, adapter, index, scorer in groups:
            now = scorer.observed({v: observed(v)[lanes] for v in scorer.views}, partner_actions[lanes])
            for j in np.flatnonzero(adapter.update(now, states[lanes], partner_actions[lanes])).tolist():
                outcomes[lanes[j]].switches += 1
            if scoring(frame):
                rule(frame, (lanes, adapter, index), seat.choice, outcomes)
        if scores is not None:
            scores[:, frame] = scored_by.observed({v: observed(v) for v in scored_by.views}, partner_actions)
        if pairs is not None:
            seen.append(observed("world").copy())
            pairs[:, frame] = np.stack(actions, axis=1)

    try:
        play_lanes(batch, bait_first(partner_role, partners, seat), each_frame)
    except PartnerError as error:
        partner, _, seed = games[error.lane]
        raise PartnerError(f"partner {partner}, seed {seed}: {error.problem}") from None
    for lanes, adapter, *_ in groups:
        for lane, guarded in zip(lanes.tolist(), adapter.guarded.tolist(), strict=True):
            outcomes[lane].guarded = guarded
    values = np.stack(seen, axis=1) if record else None
    for lane, kpm in enumerate(batch.kills_per_minute().tolist()):
        o = outcomes[lane]
        o.kills_per_minute = kpm
        if scores is not None:
            o.scores = scores[lane]
        if pairs is not None:
            o.values, o.pairs = values[lane], pairs[lane]
            o.actions = o.pairs[:, ROLES.index(partner_role)]
    return outcomes


def rule(
    frame: int,
    group: tuple[np.ndarray, AdapterLanes, np.ndarray],
    choice: np.ndarray,
    outcomes: list[Outcome],
) -> None:
    """The adapter's ruling on scoring frame `frame` for the lanes of one adaptive `group` (its
    lanes, its adapters, its policies' indices in our seat's `choice`): each lane plays its
    adapter's choice from the next frame, and a lane whose policy changes notes it in its timeline."""
    lanes, adapter, index = group
    for j in np.flatnonzero(choice[lanes] != index[adapter.policy]).tolist():
        choice[lanes[j]] = index[adapter.policy[j]]
        chosen = (adapter.payoff.types[adapter.partner[j]], adapter.payoff.ours[adapter.policy[j]])
        outcomes[lanes[j]].timeline.append((frame + 1, *chosen))


def play_teams(
    teams: list[tuple[SeatSpec, SeatSpec]],
    seeds: list[int],
    config: GameConfig | None = None,
    record: bool = False,
    world_of: str = "",
) -> np.ndarray | tuple[np.ndarray, ...]:
    """The (teams, seeds) kills/min of games of (bait partner, shooter partner), one per
    team and seed, as the lanes of one batch: both seats played by partners (stand-ins, library
    keys, wrappers). With `record`, also the (teams, seeds, frames, 2) actions, bait first, and
    the (teams, seeds, frames + 1) flags of the states in which the fortress has just fired (opened);
    with `world_of` a role, also the (teams, seeds, frames, OBS_SIZE) world view of its seat in each
    frame's state (what a fit of that seat's person reads)."""
    from services.sim.batch import BatchGame
    from services.sim.batch_play import play_lanes

    keys = np.array([seed for _ in teams for seed in seeds], np.int64)
    batch = BatchGame(len(keys), config, keys)
    seats = [Partners([team[i] for team in teams for _ in seeds], role, keys) for i, role in enumerate(ROLES)]
    played = np.zeros((len(keys), batch.config.frames, 2), np.int64) if record else None
    opened = np.zeros((len(keys), batch.config.frames + 1), bool)
    world = np.zeros((len(keys), batch.config.frames, OBS_SIZE), np.float32) if world_of else None

    def each_frame(frame: int, seen_by: list, actions: list[np.ndarray]) -> None:
        if played is not None:
            played[:, frame] = np.stack(actions, axis=1)
        if world is not None:
            world[:, frame] = seen_by[ROLES.index(world_of)]("world")
        if frame:  # the state the last step left
            opened[:, frame] = batch.state.vulnerable == batch.config.vulnerable_frames

    play_lanes(batch, seats, each_frame)
    opened[:, int(batch.state.frame[0])] = batch.state.vulnerable == batch.config.vulnerable_frames
    shape = (len(teams), len(seeds))
    kills = batch.kills_per_minute().reshape(shape)
    if played is None:
        return kills
    recorded = kills, played.reshape(*shape, -1, 2), opened.reshape(*shape, -1)
    return recorded if world is None else (*recorded, world.reshape(*shape, batch.config.frames, -1))


def batches(items: list, workers: int, lanes: int = LANES) -> list[list]:
    """Consecutive slices of `items`, of even sizes, to play as batches: at most `lanes` each, and
    at least one per worker. (The fewer the batches, the fewer the calls per game: a frame costs
    about the same whether a policy answers for ten lanes or a hundred.)"""
    count = min(len(items), max(math.ceil(len(items) / lanes), workers))
    bounds = [len(items) * i // count for i in range(count + 1)] if count else [0]
    return [items[a:b] for a, b in itertools.pairwise(bounds)]


def play_session(partner: SeatSpec, agent: SeatSpec, person: int, role: str) -> list[Outcome]:
    """The trials of one session (human_like.SESSION_TRIALS games, seeds person * trials + i) with
    the same partner, one after the other; an adaptive agent's adapter in each trial is the
    previous one's `next_trial()`."""
    config = agent.adaptive(role)
    adapters = {config: core.build_lanes(config, 1, setup(role, config.partners).payoff)} if config else {}
    outcomes: list[Outcome] = []
    for trial in range(SESSION_TRIALS):
        outcomes += play_games([(partner, agent, person * SESSION_TRIALS + trial)], role, adapters=adapters)
        adapters = {a: lanes.next_trial() for a, lanes in adapters.items()}
    return outcomes
