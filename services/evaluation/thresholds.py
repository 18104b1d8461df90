"""The out-of-library thresholds (calibration.json): how far below a library policy's own
similarity a partner's may fall before the adapter calls it out of library; and the same for the
grown library's partner groups (their members' own similarity, written into groups.json)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from services.adapter.cem import log_probs
from services.adapter.core import groups_path
from services.agent import library, networks
from services.evaluation import identification
from services.evaluation.evaluate import batches, play_games, setup
from services.evaluation.identification import windowed
from services.jobs.core import spec
from services.jobs.kinds import Progress, Runner, in_process
from services.population.partners import build
from services.population.seat import SeatSpec
from shared.game import ROLES, GameConfig, other

JOB_GAMES = 3  # games of one job: three games' streams stay under a message's 64 KiB

KINDS = {
    "calibrate": f"{__name__}:run_calibrate_jobs"
} | identification.KINDS  # what it runs, for services/jobs
CONFUSION_WINDOWS = (150, 400, 800)  # the groups' confusion is measured at these windows
HERE = in_process(KINDS)  # the runner that plays them in this process


def _self_scores(games: list[list], role: str) -> np.ndarray:
    """log pi(a | s) of `role`'s policies' own actions over games of [policy, teammate, seed] (one
    policy's), (games, frames), the games as the lanes of one batch."""
    policy = build(SeatSpec.parse(games[0][0]), role)
    seats = [(SeatSpec.parse(k), SeatSpec.parse(mate, "--agent"), int(seed)) for k, mate, seed in games]
    played = play_games(seats, other(role), record=True)
    return np.array([log_probs([policy], o.values, o.actions)[:, 0] for o in played])


def run_calibrate_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `calibrate` jobs ({role, games: [[policy, teammate, seed]...]}):
    the games' streams, one after another (a job written before jobs named the role: a library key's)."""
    return [
        _self_scores(job["games"], job.get("role") or networks.load(job["games"][0][0]).role).ravel().tolist()
        for job in args
    ]


def calibrate(
    windows: Iterable[int] = (100, 150, 200, 300, 400, 600, 800, 1000),
    seeds: list[int] | None = None,
    quantile: float = 0.01,
    margin: float = 2.0,
    run: Runner = HERE,
    progress: Progress | None = None,
    partners: str = "library",
) -> dict:
    """Out-of-library thresholds: for each role and window T, the lowest (over library policies)
    `quantile` of a policy's own mean log-probability over T-frame windows of its play with every
    library policy of the other role, minus `margin` nats. A partner whose best similarity is
    below it explains its actions far worse than any library policy explains its own. The library
    is the table's (the adapter's candidates): a grown library's table need not hold every policy
    of the libraries in use. With `partners` "groups", the policies are the partner groups'
    members, each playing with the members of ours the groups' adapter chooses among."""
    seeds = seeds or [0, 1]
    if partners == "groups":  # by partner role: the groups' members, and who plays with them
        keys = {other(ours): list(setup(ours, partners).payoff.partners) for ours in ROLES}
        mates = {other(ours): list(setup(ours, partners).payoff.ours) for ours in ROLES}
    else:
        keys = {role: list(setup(role).payoff.ours) for role in ROLES}
        mates = {role: keys[other(role)] for role in ROLES}
    by_policy = [  # each policy's games with every teammate and seed
        [[k, mate, seed] for mate in mates[role] for seed in seeds] for role in ROLES for k in keys[role]
    ]
    tasks = [game for games in by_policy for game in games]
    frames = GameConfig().frames
    parts = [part for games in by_policy for part in batches(games, 1, JOB_GAMES)]
    role_of = {k: role for role in ROLES for k in keys[role]}
    todo = [
        spec(f"calibrate-{i}", "calibrate", {"role": role_of[part[0][0]], "games": part}, len(part) * frames)
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
    result = {
        "quantile": quantile,
        "margin": margin,
        "seeds": seeds,
        "library": library.manifest_hash(),
        "partners": partners,
        "thresholds": thresholds,
        "self_quantiles": lowest,
    }
    if partners == "groups":  # how the filter errs on members it has not seen, by our seat
        windows = list(CONFUSION_WINDOWS)
        result["confusion"] = {
            ours: {
                str(w): r["bayes_confusion"]
                for w, r in identification.identification(ours, windows, seeds, run, leave_one_out=True)[
                    "windows"
                ].items()
            }
            for ours in ROLES
        }
    return result


def write_calibration(result: dict, path: Path) -> Path:
    """The library's calibration file; the groups' thresholds go into their groups.json at `path`,
    each seat of ours given its partners' thresholds."""
    if result.get("partners") == "groups":
        record = json.loads((path if path.exists() else groups_path()).read_text())
        for ours, seat in record["seats"].items():
            seat["thresholds"] = result["thresholds"][other(ours)]
            seat["confusion"] = result["confusion"][ours]
        result = record
    path.write_text(json.dumps(result, indent=1) + "\n")
    return path
