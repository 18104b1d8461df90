"""Identification: library partners with 10 % action noise play with our best response to them; at
every frame with a full window, is the most similar library policy the true one? Also the
confusion matrix, and how many frames the estimate takes to follow a partner that switched."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from services.adapter.core import (
    Adapter,
    AdapterConfig,
    Payoff,
)
from services.adapter.evaluate import play_partner, run_parallel, setup
from services.adapter.partners import SWITCH_AT, Noisy, Switching, make_partner
from shared.game import other

FOLLOW_HOLD = 30  # frames the estimate must stay on the new type to count as following it


def windowed(scores: np.ndarray, window: int) -> np.ndarray:
    """Means over every full window of `window` frames: row i covers frames i .. i + window - 1."""
    sums = np.cumsum(np.vstack([np.zeros(scores.shape[1]), scores]), axis=0)
    return (sums[window:] - sums[:-window]) / window


def bayes_estimates(scores: np.ndarray, config: AdapterConfig, payoff: Payoff) -> np.ndarray:
    """The Bayesian filter's most likely type at every frame (the same code the adapter runs)."""
    adapter = Adapter(config, payoff)
    estimates = np.empty(len(scores), dtype=int)
    for t, row in enumerate(scores):
        adapter.forward(row)
        estimates[t] = int(np.argmax(adapter.log_belief))
    return estimates


def _stream(partner: str, teammate: str, seed: int, role: str) -> np.ndarray:
    """Scores of a noisy partner's frames (rows) under each library policy of its role (columns)."""
    s = setup(role)
    outcome = play_partner(Noisy(make_partner(partner, other(role))), teammate, seed, role, record=True)
    return s.scorer.batch(np.array(outcome.values), np.array(outcome.actions))


def switch_scores(first: str, second: str, seed: int, role: str) -> np.ndarray:
    """Scores of a noisy partner that switches from `first` to `second` at SWITCH_AT, playing with
    our best response to `first` (what the adaptive agent plays before the switch)."""
    s, partner_role = setup(role), other(role)
    teammate = s.payoff.ours[s.payoff.best_response(s.payoff.partners.index(first))]
    switching = Switching(make_partner(first, partner_role), make_partner(second, partner_role))
    outcome = play_partner(Noisy(switching), teammate, seed, role, record=True)
    return s.scorer.batch(np.array(outcome.values), np.array(outcome.actions))


def follow_lag(estimates: np.ndarray, target: int, start: int, hold: int = FOLLOW_HOLD) -> int | None:
    """Frames from `start` until the estimate is `target` and stays so for `hold` frames (or to the end)."""
    run = 0
    for t in range(start, len(estimates)):
        run = run + 1 if estimates[t] == target else 0
        if run >= hold or (run and t == len(estimates) - 1):
            return t - run + 1 - start
    return None


def identification(
    role: str,
    windows: list[int],
    seeds: list[int],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Identification of library partners (10 % action noise) by the CEM window and by the filter."""
    s = setup(role)
    keys = list(s.payoff.partners)
    teammate = {k: s.payoff.ours[s.payoff.best_response(i)] for i, k in enumerate(keys)}
    pairs = [(a, b) for a in keys for b in keys if a != b]
    tasks = [(k, teammate[k], seed, role) for k in keys for seed in seeds]
    switch_tasks = [(a, b, seed, role) for a, b in pairs for seed in seeds[:1]]
    total = len(tasks) + len(switch_tasks)
    streams = run_parallel(_stream, tasks, workers, progress and (lambda d, _: progress(d, total)))
    switched = run_parallel(
        switch_scores, switch_tasks, workers, progress and (lambda d, _: progress(len(tasks) + d, total))
    )
    out: dict = {"partners": keys, "seeds": seeds, "noise": 0.1, "windows": {}}
    for window in windows:
        confusion = np.zeros((len(keys), len(keys)), dtype=int)
        bayes_right = bayes_total = 0
        config = AdapterConfig(role, window, "bayes")
        for (key, *_), scores in zip(tasks, streams, strict=True):
            estimates = windowed(scores, window).argmax(axis=1)
            np.add.at(confusion[keys.index(key)], estimates, 1)
            bayes = bayes_estimates(scores, config, s.payoff)[window - 1 :]
            bayes_right += int((bayes == keys.index(key)).sum())
            bayes_total += len(bayes)
        lags, bayes_lags = [], []
        for (_, second, *_), scores in zip(switch_tasks, switched, strict=True):
            target = keys.index(second)
            estimates = np.concatenate([np.full(window - 1, -1), windowed(scores, window).argmax(axis=1)])
            lags.append(follow_lag(estimates, target, SWITCH_AT))
            bayes_lags.append(follow_lag(bayes_estimates(scores, config, s.payoff), target, SWITCH_AT))
        out["windows"][window] = {
            "accuracy": float(np.trace(confusion) / confusion.sum()),
            "bayes_accuracy": bayes_right / bayes_total,
            "confusion": confusion.tolist(),
            "follow": _lag_summary(lags, window),
            "bayes_follow": _lag_summary(bayes_lags, window),
        }
    return out


def _lag_summary(lags: list[int | None], window: int) -> dict:
    followed = [lag for lag in lags if lag is not None]
    return {
        "switches": len(lags),
        "followed": len(followed),
        "median_frames": float(np.median(followed)) if followed else None,
        "within_half_window": sum(lag <= window / 2 for lag in followed) / len(lags) if lags else 0.0,
    }
