"""Identification: library partners with 10 % action noise play with our best response to them; at
every frame with a full window, is the most similar library policy the true one? Also the
confusion matrix, and how many frames the estimate takes to follow a partner that switched."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from services.adapter.core import AdapterConfig, Payoff, forward
from services.adapter.evaluate import batches, games_done, play_games, run_parallel, setup
from services.adapter.partners import SWITCH_AT

FOLLOW_HOLD = 30  # frames the estimate must stay on the new type to count as following it


def windowed(scores: np.ndarray, window: int) -> np.ndarray:
    """Means over every full window of `window` frames: row i covers frames i .. i + window - 1."""
    sums = np.cumsum(np.vstack([np.zeros(scores.shape[1]), scores]), axis=0)
    return (sums[window:] - sums[:-window]) / window


def bayes_estimates(scores: np.ndarray, config: AdapterConfig, payoff: Payoff) -> np.ndarray:
    """The Bayesian filter's most likely type at every frame of every stream, (streams, frames),
    from (streams, frames, K) scores (the same update the adapter runs, all streams at once)."""
    k = len(payoff.partners)
    log_belief = np.full((len(scores), k), -math.log(k))
    estimates = np.empty(scores.shape[:2], dtype=int)
    for t in range(scores.shape[1]):
        log_belief = forward(log_belief, scores[:, t], config)
        estimates[:, t] = np.argmax(log_belief, axis=1)
    return estimates


def _scores(games: list[tuple[str, str, int]], role: str) -> list[np.ndarray]:
    """Each game's partner scores: frames (rows) under each library policy of its role (columns)."""
    return [outcome.scores for outcome in play_games(games, role, record=True)]


def _switch_game(first: str, second: str, seed: int, role: str) -> tuple[str, str, int]:
    """A noisy partner that switches from `first` to `second` at SWITCH_AT, playing with our best
    response to `first` (what the adaptive agent plays before the switch)."""
    payoff = setup(role).payoff
    teammate = payoff.ours[payoff.best_response(payoff.partners.index(first))]
    return f"noisy(switch({first},{second}))", teammate, seed


def switch_scores(first: str, second: str, seed: int, role: str) -> np.ndarray:
    """The scores of one `_switch_game`."""
    return _scores([_switch_game(first, second, seed, role)], role)[0]


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
    tasks = [(k, seed) for k in keys for seed in seeds]
    switch_tasks = [(a, b) for a, b in pairs for _ in seeds[:1]]
    games = [(f"noisy({k})", teammate[k], seed) for k, seed in tasks]
    games += [_switch_game(a, b, seeds[0], role) for a, b in switch_tasks]
    parts = batches(games, workers)
    played = run_parallel(
        _scores, [(part, role) for part in parts], workers, progress and games_done(parts, progress)
    )
    scores = np.stack([stream for part in played for stream in part])
    streams, switched = scores[: len(tasks)], scores[len(tasks) :]
    out: dict = {"partners": keys, "seeds": seeds, "noise": 0.1, "windows": {}}
    for window in windows:
        confusion = np.zeros((len(keys), len(keys)), dtype=int)
        config = AdapterConfig(role, window, "bayes")
        for (key, _), stream in zip(tasks, streams, strict=True):
            estimates = windowed(stream, window).argmax(axis=1)
            np.add.at(confusion[keys.index(key)], estimates, 1)
        truth = np.array([keys.index(key) for key, _ in tasks])
        bayes = bayes_estimates(streams, config, s.payoff)[:, window - 1 :]
        bayes_right, bayes_total = int((bayes == truth[:, None]).sum()), bayes.size
        lags, bayes_lags = [], []
        bayes_switched = bayes_estimates(switched, config, s.payoff)
        for (_, second), stream, filtered in zip(switch_tasks, switched, bayes_switched, strict=True):
            target = keys.index(second)
            estimates = np.concatenate([np.full(window - 1, -1), windowed(stream, window).argmax(axis=1)])
            lags.append(follow_lag(estimates, target, SWITCH_AT))
            bayes_lags.append(follow_lag(filtered, target, SWITCH_AT))
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
