"""The out-of-library thresholds (calibration.json): how far below a library policy's own
similarity a partner's may fall before the adapter calls it out of library."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from services.adapter.cem import log_probs
from services.agent import library, networks
from services.evaluation.evaluate import batches, play_games, setup
from services.evaluation.identification import windowed
from services.jobs.core import spec
from services.jobs.kinds import Progress, Runner, in_process
from services.population.seat import SeatSpec
from shared.game import ROLES, GameConfig, other

JOB_GAMES = 3  # games of one job: three games' streams stay under a message's 64 KiB

KINDS = {"calibrate": f"{__name__}:run_calibrate_jobs"}  # the job kinds it runs, for services/jobs
HERE = in_process(KINDS)  # the runner that plays them in this process


def _self_scores(games: list[list]) -> np.ndarray:
    """log pi(a | s) of library policies' own actions over games of [policy, teammate, seed] (one
    policy's), (games, frames), the games as the lanes of one batch."""
    policy = networks.load(games[0][0])
    seats = [(SeatSpec.parse(k), SeatSpec.parse(mate), int(seed)) for k, mate, seed in games]
    played = play_games(seats, other(policy.role), record=True)
    return np.array([log_probs([policy], o.values, o.actions)[:, 0] for o in played])


def run_calibrate_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `calibrate` jobs ({games: [[policy, teammate, seed]...]}): the
    games' streams, one after another."""
    return [_self_scores(job["games"]).ravel().tolist() for job in args]


def calibrate(
    windows: Iterable[int] = (100, 150, 200, 300, 400, 600, 800, 1000),
    seeds: list[int] | None = None,
    quantile: float = 0.01,
    margin: float = 2.0,
    run: Runner = HERE,
    progress: Progress | None = None,
) -> dict:
    """Out-of-library thresholds: for each role and window T, the lowest (over library policies)
    `quantile` of a policy's own mean log-probability over T-frame windows of its play with every
    library policy of the other role, minus `margin` nats. A partner whose best similarity is
    below it explains its actions far worse than any library policy explains its own. The library
    is the table's (the adapter's candidates): a grown library's table need not hold every policy
    of the libraries in use."""
    seeds = seeds or [0, 1]
    keys = {role: list(setup(role).payoff.ours) for role in ROLES}
    by_policy = [  # each library policy's games with every teammate and seed
        [[k, mate, seed] for mate in keys[other(role)] for seed in seeds]
        for role in ROLES
        for k in keys[role]
    ]
    tasks = [game for games in by_policy for game in games]
    frames = GameConfig().frames
    parts = [part for games in by_policy for part in batches(games, 1, JOB_GAMES)]
    todo = [
        spec(f"calibrate-{i}", "calibrate", {"games": part}, len(part) * frames)
        for i, part in enumerate(parts)
    ]
    streams = [stream for values in run(todo, progress) for stream in np.reshape(values, (-1, frames))]
    thresholds: dict[str, dict[str, float]] = {role: {} for role in ROLES}
    lowest: dict[str, dict[str, dict[str, float]]] = {role: {} for role in ROLES}
    for window in windows:
        means = [windowed(s[:, None], window)[:, 0] for s in streams]
        for role in ROLES:
            per_policy = {}
            for k in keys[role]:
                mine = np.concatenate([m for (key, *_), m in zip(tasks, means, strict=True) if key == k])
                per_policy[k] = float(np.quantile(mine, quantile))
            lowest[role][str(window)] = per_policy
            thresholds[role][str(window)] = min(per_policy.values()) - margin
    return {
        "quantile": quantile,
        "margin": margin,
        "seeds": seeds,
        "library": library.manifest_hash(),
        "thresholds": thresholds,
        "self_quantiles": lowest,
    }


def write_calibration(result: dict, path: Path) -> Path:
    path.write_text(json.dumps(result, indent=1) + "\n")
    return path
