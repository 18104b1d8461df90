"""The guard: it counts the team's kills from states and trips only when the promise fails."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from services.adapter.core import build
from services.adapter.guard import GUARD_FRAMES, Guard, poisson_cdf
from services.evaluation.evaluate import play_games
from services.evaluation.evaluate_test import seated
from services.population.adaptive import AdapterConfig
from services.sim import observation as ob


@pytest.mark.parametrize(("k", "mean"), [(0, 0.5), (3, 4.0), (10, 2.5)])
def test_poisson_cdf(k, mean):
    assert poisson_cdf(k, mean) == pytest.approx(stats.poisson.cdf(k, mean), rel=1e-12)


def frames(kill_every: int, n: int) -> list[list[float]]:
    """World-view values where the fortress goes down once every `kill_every` frames."""
    out = []
    for t in range(n):
        values = np.zeros(ob.TIME + 1)
        values[ob.FORTRESS + ob.F_ALIVE] = 0.0 if t % kill_every == kill_every - 1 else 1.0
        values[ob.SELF + ob.ALIVE] = values[ob.PARTNER + ob.ALIVE] = 1.0
        out.append(values.tolist())
    return out


def test_the_guard_trips_when_kills_fall_short_of_the_promise_and_not_before():
    """Lanes: one kept promise, one broken, and the best static policy (index 5), never left."""
    kept, broken, best = range(3)
    guard = Guard(5, 3)
    guard.start(np.arange(3), np.array([7, 7, 5]), np.full(3, 8.0))
    for a, b in zip(frames(225, GUARD_FRAMES * 2), frames(10**6, GUARD_FRAMES * 2), strict=True):
        guard.watch(np.array([a, b, b]))  # 8 kills/min for 30 s in the kept lane; none elsewhere
        tripped = guard.breached(np.ones(3, bool))
        assert not (tripped[broken] and guard.frames[broken] < GUARD_FRAMES)
    assert guard.kills.tolist() == [4, 0, 0]
    assert guard.breached(np.ones(3, bool)).tolist() == [False, True, False]
    assert not guard.breached(np.array([True, False, True])).any()  # a lane not asked: no answer


def test_a_guarded_game_switches_at_most_once_more_and_reports_it():
    config = AdapterConfig("shooter", 400, "bayes-dwell-ood-guard")
    plain = AdapterConfig("shooter", 400, "bayes-dwell-ood")
    outcome, plain = play_games(seated([("human(B3)", config, 1), ("human(B3)", plain, 1)]), "shooter")
    assert outcome.switches <= plain.switches + 1
    if outcome.guarded:  # fell back to the best static policy
        payoff = build(AdapterConfig("shooter")).payoff
        assert outcome.timeline[-1][2] == payoff.ours[payoff.best_average()]


def test_memory_carries_the_adapter_into_the_next_trial():
    scores = np.log(np.full(9, 1 / 12))
    scores[2] = np.log(0.9)  # the partner plays like B3
    remembering = build(AdapterConfig("shooter", 150, "bayes-dwell-ood-guard-memory"))
    forgetting = build(AdapterConfig("shooter", 150, "bayes-dwell-ood-guard"))
    for adapter in (remembering, forgetting):
        for v in frames(10**6, 200):
            adapter.update(scores, v)
    initial = forgetting.payoff.initial(forgetting.config)  # the best static policy of the table
    assert remembering.partner == forgetting.partner == "B3" and remembering.policy != initial
    carried, fresh = remembering.next_trial(), forgetting.next_trial()
    guard = carried.lanes.guard
    assert carried is remembering and guard.last is None and guard.frames[0] > 0
    assert fresh.partner == "" and fresh.policy == initial and fresh.frames == 0


def flipping_switches(strategy: str) -> list[int]:
    """The frames an adapter switches at with a partner that flips between B3 and B9 every 2 s."""
    adapter, switched = build(AdapterConfig("shooter", 150, strategy, warmup=1)), []
    for t in range(1800):
        scores = np.log(np.full(9, 1 / 12))
        scores[2 if (t // 60) % 2 else 8] = np.log(0.95)
        if adapter.update(scores):
            switched.append(t)
    return switched


def test_under_the_guard_every_switch_doubles_the_dwell():
    assert len(flipping_switches("bayes-dwell-ood")) > 10
    switched = flipping_switches("bayes-dwell-ood-guard")
    assert 1 <= len(switched) <= 7
    gaps = np.diff(switched)
    assert all(gap >= 15 * 2 ** (i + 1) for i, gap in enumerate(gaps))
