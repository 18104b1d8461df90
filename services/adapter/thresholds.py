"""The out-of-library thresholds (calibration.json): how far below a library policy's own
similarity a partner's may fall before the adapter calls it out of library."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from services.adapter.cem import log_probs
from services.adapter.evaluate import play_partner
from services.adapter.identification import windowed
from services.adapter.partners import make_partner
from services.agent import library, networks
from services.jobs.core import spec
from services.jobs.kinds import Progress, Runner, in_process
from shared.game import ROLES, GameConfig, other


def _self_scores(key: str, teammate: str, seed: int) -> np.ndarray:
    """log pi(a | s) of a library policy's own actions over one game with `teammate`."""
    policy = networks.load(key)
    partner_role = other(policy.role)
    outcome = play_partner(make_partner(key, policy.role), teammate, seed, partner_role, record=True)
    return log_probs([policy], outcome.values, outcome.actions)[:, 0]


def run_calibrate_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `calibrate` jobs ({policy, teammate, seed}): each game's stream."""
    return [_self_scores(a["policy"], a["teammate"], int(a["seed"])).tolist() for a in args]


def calibrate(
    windows: Iterable[int] = (100, 150, 200, 300, 400, 600, 800, 1000),
    seeds: list[int] | None = None,
    quantile: float = 0.01,
    margin: float = 2.0,
    run: Runner = in_process,
    progress: Progress | None = None,
) -> dict:
    """Out-of-library thresholds: for each role and window T, the lowest (over library policies)
    `quantile` of a policy's own mean log-probability over T-frame windows of its play with every
    library policy of the other role, minus `margin` nats. A partner whose best similarity is
    below it explains its actions far worse than any library policy explains its own."""
    seeds = seeds or [0, 1]
    tasks = [
        (k, mate, seed)
        for k in library.registry()
        for mate in library.keys(other(_role(k)))
        for seed in seeds
    ]
    frames = GameConfig().frames
    todo = [
        spec(
            f"calibrate-{k}-{mate}-{seed}", "calibrate", {"policy": k, "teammate": mate, "seed": seed}, frames
        )
        for k, mate, seed in tasks
    ]
    streams = [np.array(values) for values in run(todo, progress)]
    thresholds: dict[str, dict[str, float]] = {role: {} for role in ROLES}
    lowest: dict[str, dict[str, dict[str, float]]] = {role: {} for role in ROLES}
    for window in windows:
        means = [windowed(s[:, None], window)[:, 0] for s in streams]
        for role in ROLES:
            per_policy = {}
            for k in library.keys(role):
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


def _role(key: str) -> str:
    return library.registry()[key].role


def write_calibration(result: dict, path: Path) -> Path:
    path.write_text(json.dumps(result, indent=1) + "\n")
    return path
