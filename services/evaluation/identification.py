"""Identification: library partners with 10 % action noise play with our best response to them; at
every frame with a full window, is the most similar library policy the true one? Also the
confusion matrix, and how many frames the estimate takes to follow a partner that switched."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from services.adapter.core import Payoff, forward
from services.evaluation.evaluate import Setup, batches, play_games, setup
from services.jobs.core import spec
from services.jobs.kinds import Runner, in_process
from services.population.adaptive import AdapterConfig
from services.population.seat import SeatSpec
from services.population.wrappers import SWITCH_AT
from shared.game import check_role

FOLLOW_HOLD = 30  # frames the estimate must stay on the new type to count as following it
JOB_GAMES = 32  # games of an identification job: the default's 99 games spread over 4 workers

KINDS = {"identify": f"{__name__}:run_identify_jobs"}  # the job kinds it runs, for services/jobs
HERE = in_process(KINDS)  # the runner that plays them in this process


def windowed(scores: np.ndarray, window: int) -> np.ndarray:
    """Means over every full window of `window` frames: row i covers frames i .. i + window - 1."""
    sums = np.cumsum(np.vstack([np.zeros(scores.shape[1]), scores]), axis=0)
    return (sums[window:] - sums[:-window]) / window


def bayes_estimates(scores: np.ndarray, config: AdapterConfig, payoff: Payoff) -> np.ndarray:
    """The Bayesian filter's most likely type (payoff.types: a group's belief is its members') at
    every frame of every stream, (streams, frames), from (streams, frames, K) scores (the same
    update the adapter runs, all streams at once)."""
    k, membership = len(payoff.partners), payoff.membership
    log_belief = np.full((len(scores), k), -math.log(k))
    estimates = np.empty(scores.shape[:2], dtype=int)
    for t in range(scores.shape[1]):
        log_belief = forward(log_belief, scores[:, t], config)
        estimates[:, t] = np.argmax(np.exp(log_belief) @ membership, axis=1)
    return estimates


def _scores(games: list[tuple[str, str, int]], role: str, partners: str = "library") -> list[np.ndarray]:
    """Each game's partner scores: frames (rows) under each partner type's policy (columns)."""
    seats = [(SeatSpec.parse(p), SeatSpec.parse(a, "--agent"), seed) for p, a, seed in games]
    return [outcome.scores for outcome in play_games(seats, role, score=partners)]


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


def _game_counts(
    stream: np.ndarray, windows: list[int], truth: int, target: int, s: Setup, left_out: int = -1
) -> list[list]:
    """What identification keeps of one game's scores, per window: [confusion row counts of the CEM
    estimate, and of the filter's] for a partner of type `truth`, and [lag of the CEM estimate, lag
    of the filter] for a partner that switched to type `target` (-1 where it does not apply). With
    `left_out` a partner policy's index, the game is scored as if that policy were not among them:
    a partner the types have never held (leave one out)."""
    payoff = s.payoff
    if left_out >= 0:
        stream, payoff = np.delete(stream, left_out, axis=1), _without(payoff, left_out)
    to_type = np.argmax(payoff.membership, axis=1)
    out = []
    for window in windows:
        config = AdapterConfig(s.role, window, "bayes")
        bayes = bayes_estimates(stream[None], config, payoff)[0]
        if target >= 0:
            estimates = np.concatenate([np.full(window - 1, -1), windowed(stream, window).argmax(axis=1)])
            lags = [follow_lag(estimates, target, SWITCH_AT), follow_lag(bayes, target, SWITCH_AT)]
            out.append([[], [], *lags])
        else:
            estimates = to_type[windowed(stream, window).argmax(axis=1)]
            counts = np.bincount(estimates, minlength=len(payoff.types))
            filtered = np.bincount(bayes[window - 1 :], minlength=len(payoff.types))
            out.append([counts.tolist(), filtered.tolist(), None, None])
    return out


def _without(payoff: Payoff, k: int) -> Payoff:
    """The payoff without partner policy k (its group keeps its name and row)."""
    keep = [i for i in range(len(payoff.partners)) if i != k]
    return replace(
        payoff,
        partners=tuple(payoff.partners[i] for i in keep),
        values=payoff.values[keep],
        group=tuple(payoff.group[i] for i in keep) if payoff.groups else (),
    )


def run_identify_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `identify` jobs ({role, windows, games: [[partner, our policy,
    seed, true type, switched to]...]})."""
    out = []
    for job in args:
        partners = job.get("partners", "library")
        s, windows = setup(check_role(job["role"]), partners), [int(w) for w in job["windows"]]
        games = [(partner, ours, int(seed)) for partner, ours, seed, *_ in job["games"]]
        streams = _scores(games, s.role, partners)
        out.append(
            [
                _game_counts(stream, windows, int(t), int(to), s, int(left[0]) if left else -1)
                for stream, (_, _, _, t, to, *left) in zip(streams, job["games"], strict=True)
            ]
        )
    return out


def identification(
    role: str,
    windows: list[int],
    seeds: list[int],
    run: Runner = HERE,
    progress: Callable[[int, int], None] | None = None,
    job_games: int | None = None,
    held_out: dict[str, str] | None = None,
    leave_one_out: bool = False,
) -> dict:
    """Identification of library partners (10 % action noise) by the CEM window and by the filter;
    the games are jobs of at most `job_games` games, run by `run` (here, or on workers). As the
    grown library's partner groups: with `held_out` (partner -> its group), of those partners
    (members the groups never held); with `leave_one_out`, of every member of the groups, each
    scored as if it were not among them. Each partner plays with its type's best member of ours."""
    partners = "groups" if held_out or leave_one_out else "library"
    s = setup(role, partners)
    keys = list(s.payoff.types)
    to_type = np.argmax(s.payoff.membership, axis=1)
    rows = s.payoff.values[np.argmax(s.payoff.membership, axis=0)]  # each type's row
    teammate = {k: s.payoff.ours[int(np.argmax(rows[i]))] for i, k in enumerate(keys)}
    if held_out:
        truth = {p: keys.index(g) for p, g in held_out.items()}
        games = [
            [f"noisy({p})", teammate[held_out[p]], seed, t, -1] for p, t in truth.items() for seed in seeds
        ]
    elif leave_one_out:
        games = [
            [f"noisy({p})", teammate[keys[to_type[i]]], seed, int(to_type[i]), -1, i]
            for i, p in enumerate(s.payoff.partners)
            for seed in seeds
        ]
    else:
        games = [[f"noisy({k})", teammate[k], seed, keys.index(k), -1] for k in keys for seed in seeds]
        games += [
            [*_switch_game(a, b, seeds[0], role), -1, keys.index(b)] for a in keys for b in keys if a != b
        ]
    args = {"role": role, "windows": windows, "partners": partners}
    todo = [
        spec(f"identify-{i}", "identify", args | {"games": part}, len(part))
        for i, part in enumerate(batches(games, 1, job_games or JOB_GAMES))
    ]
    counted = [game for values in run(todo, progress) for game in values]
    out: dict = {"partners": keys, "seeds": seeds, "noise": 0.1, "windows": {}}
    if held_out:
        out["held_out"] = held_out
    for w, window in enumerate(windows):
        confusion = np.zeros((len(keys), len(keys)), dtype=int)
        filtered = np.zeros((len(keys), len(keys)), dtype=int)
        lags, bayes_lags = [], []
        for (_, _, _, truth, target, *_), by_window in zip(games, counted, strict=True):
            counts, bayes_counts, lag, bayes_lag = by_window[w]
            if target >= 0:
                lags.append(lag)
                bayes_lags.append(bayes_lag)
            else:
                confusion[truth] += counts
                filtered[truth] += bayes_counts
        out["windows"][window] = {
            "accuracy": float(np.trace(confusion) / confusion.sum()),
            "bayes_accuracy": float(np.trace(filtered) / filtered.sum()),
            "confusion": confusion.tolist(),
            "bayes_confusion": filtered.tolist(),
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
