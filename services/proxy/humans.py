"""Stand-ins for people measured and fitted (docs/humans.md): the calibration, how human-like
partners of each skill score in pairs and with library teammates against the study's human pairs
(about 2.6 kills/min); and `tsf humans fit`, a stand-in per participant from recordings: its
policy, skill and the model's own parameters (holds read off the keys, the rest by a regression
calibrated on simulated stand-ins of known parameters), which the stand-in plays with.

Three groups of teams per skill, each bait policy paired as the shipped table pairs it:
- **pairs**: `human(Bk)` with `human(S)`, S the table's best shooter for Bk, both of that skill;
- **bait stand-in**: `human(Bk)` with that library shooter S itself;
- **shooter stand-in**: `human(Sj)` with the table's best library bait for Sj.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.agent import library, networks
from services.evaluation.evaluate import play_teams
from services.population.human_like import (
    FRAME_MS,
    HISTORY,
    PARAMETERS,
    SKILLS,
    STAND_INS,
    in_view,
    predict,
    rules_of,
)
from services.population.keys import LAPSE, changes, fire_presses, shortest_runs, still
from services.population.seat import seats_of
from services.proxy.data import pairs, person_seats, study_record
from services.recorder.recording import load
from services.sim import observation as ob
from services.sim.sampling import batch_probs
from services.table.table import Table
from shared.errors import Failure, UsageError
from shared.game import FPS, ROLES, GameConfig, other, split_action

GROUPS = ("pairs", "bait stand-in", "shooter stand-in")
STUDY_PAIRS = 2.6  # kills/min: the original study's human-human teams


@dataclass(frozen=True)
class Row:
    """One group at one skill: mean kills/min over its teams and seeds, its standard error."""

    skill: str
    group: str
    mean: float
    stderr: float
    games: int


def teams(skill: str, table: Table) -> dict[str, list[tuple[str, str]]]:
    """The (bait, shooter) partner names of every group at `skill` (a SKILLS name or a number)."""
    person = "" if skill == "typical" else f",skill={skill}"
    baits, shooters = library.keys("bait"), library.keys("shooter")
    best = {b: table.best_shooter(b) for b in baits}
    return {
        "pairs": [(f"human({b}{person})", f"human({best[b]}{person})") for b in baits],
        "bait stand-in": [(f"human({b}{person})", best[b]) for b in baits],
        "shooter stand-in": [(table.best_bait(s), f"human({s}{person})") for s in shooters],
    }


def calibration(
    skills: tuple[str, ...] = tuple(SKILLS), seeds: int = 12, config: GameConfig | None = None
) -> list[Row]:
    """Every group at every skill, over game seeds 0..seeds-1 (seeds // 3 people, three trials
    each), all games in one batch."""
    table = Table.load()
    plan = [
        (skill, group, team) for skill in skills for group, ts in teams(skill, table).items() for team in ts
    ]
    kills = play_teams([seats_of(team) for *_, team in plan], list(range(seeds)), config)
    rows = []
    for skill in skills:
        for group in GROUPS:
            scores = np.concatenate(
                [k for (s, g, _), k in zip(plan, kills, strict=True) if (s, g) == (skill, group)]
            )
            rows.append(
                Row(
                    skill,
                    group,
                    float(scores.mean()),
                    float(scores.std(ddof=1) / np.sqrt(len(scores))),
                    len(scores),
                )
            )
    return rows


# ---------------------------------------------------------------- stand-ins fitted from recordings

FIT_SKILLS = np.linspace(0.0, 1.0, 6)  # the skills simulated; the fit interpolates between them
FIT_SEEDS = 12  # simulated games per skill and person
FROZEN = LAPSE  # frames (0.5 s) without a key change: a lapse, or a long hold
STATISTICS = ("key_changes_per_s", "frozen_share", "response_ms", "fires_per_s", "kills_per_minute")


def statistics(actions: np.ndarray, opened: np.ndarray, kills_per_minute: float) -> dict[str, float]:
    """What a person's keys say about them, over one game's actions (frames,) and the frames at
    which the fortress opened (fired a shell): key changes per second, the share of frames in runs
    of FROZEN frames or more without a change, the median frames from an opening to the next key
    change (as ms), fire presses per second, and the game's kills/min; and the shortest key run
    (5th percentile, ms), the person's shortest press."""
    keys = np.array(split_action(actions))  # (3, frames)
    when = changes(keys)
    bounds = np.concatenate([[0], when, [len(actions)]])
    runs = np.diff(bounds)
    per_key = [np.diff(np.flatnonzero(np.diff(k) != 0)) for k in keys]
    inner = np.concatenate(per_key) if any(len(r) for r in per_key) else np.array([len(actions)])
    after = np.searchsorted(when, opened, side="right")
    latency = [when[i] - f for i, f in zip(after, opened, strict=True) if i < len(when)]
    seconds = len(actions) / FPS
    return {
        "key_changes_per_s": len(when) / seconds,
        "frozen_share": float(runs[runs >= FROZEN].sum() / len(actions)),
        "response_ms": float(np.median(latency) * FRAME_MS) if latency else 1000.0,
        "fires_per_s": float(np.sum(np.diff(keys[2]) == 1) / seconds),
        "kills_per_minute": float(kills_per_minute),
        "hold_ms": float(np.percentile(inner, 5) * FRAME_MS),
    }


@dataclass(frozen=True)
class Trial:
    """What the fit reads of one recorded trial: the person's actions, the fortress's openings,
    the score, the agent in the other seat, and the person's world-view observations and actions
    while alive (for the policy's likelihood)."""

    actions: np.ndarray
    opened: np.ndarray
    kills_per_minute: float
    agent: str
    seed: int
    alive_obs: np.ndarray
    alive_actions: np.ndarray
    cues: np.ndarray  # action indices of the events that call for a response (cues_of)
    alive: np.ndarray  # (frames,) the person's ship alive
    vulnerable: np.ndarray  # (frames,) the fortress vulnerable
    obs: np.ndarray  # (frames, 64) the person's world view of each frame's state, before its keys


def read_trial(path: Path, role: str) -> Trial:
    """One recording of a person's `role` (proxy.data's rules for whose seat it is)."""
    recording = load(path)
    if problems := recording.problems():
        raise Failure(f"{path}: damaged recording ({'; '.join(problems)}); nothing fitted")
    record = study_record(path)
    if role not in person_seats(recording, record):
        raise UsageError("RECORDINGS", path, f"no person played the {role} seat; nothing fitted")
    states = sorted(recording.states, key=lambda s: s.frame)
    seat = ROLES.index(role)
    actions = np.array([s.applied[seat] for s in states[1:]], np.int64)
    frames = np.array([s.frame for s in states[1:]])
    cued = [e.frame for e in recording.events if (e.kind, e.role) in cues_of(role)]
    cues = np.unique(np.searchsorted(frames, cued))
    alive = np.array([s.obs[role][ob.SELF + ob.ALIVE] > 0.5 for s in states[1:]])
    open_now = np.array([s.obs[role][ob.FORTRESS + ob.F_VULNERABLE] > 0.5 for s in states[1:]])
    vulnerable = np.array([s.obs[role][ob.FORTRESS + ob.F_VULNERABLE] for s in states[:-1]])
    opened = np.flatnonzero(np.diff(vulnerable) > 0.5) + 1
    obs, alive_actions, _ = pairs(recording, role)
    # what played the other seat; a study's sidecar names only the label the participant saw
    agent = recording.start.policies.get(other(role)) or record.get("agent", "")
    summary = recording.summary
    return Trial(
        actions, opened, summary.kills_per_minute, agent, recording.start.seed, obs, alive_actions,
        cues[cues < len(actions)], alive, open_now, np.array([s.obs[role] for s in states[:-1]], np.float32),
    )  # fmt: skip


KEYS = ("turn", "thrust", "fire")


def cues_of(role: str) -> set[tuple[str, str]]:
    """The events (kind, role) that call for the person's response: their own respawn, a shell
    fired at them, the fortress's respawn."""
    return {("respawn", role), ("shell", role), ("fortress_respawn", "")}


def _ms(frames: list, percent: float) -> float | None:
    """A percentile of frame counts, as ms; None (JSON null) when there are none."""
    return float(np.percentile(frames, percent) * FRAME_MS) if len(frames) else None


def traits(trials: list[Trial]) -> dict[str, float]:
    """The traits read directly off a person's trials, pooled (docs/humans.md, Traits): reaction
    (median ms from a cue to the next key change), each key's hold (median and p90 ms of its
    presses), the lapse share (alive frames in runs of LAPSE or more without a key change), fire
    presses per second and the share of them made while the fortress is vulnerable."""
    reactions, holds, lapsed, alive, presses, open_presses, frames = [], {k: [] for k in KEYS}, 0, 0, 0, 0, 0
    for t in trials:
        keys = np.array(split_action(t.actions))  # (3, frames)
        when = changes(keys)
        after = np.searchsorted(when, t.cues, side="right")
        reactions += [when[i] - c for i, c in zip(after, t.cues, strict=True) if i < len(when)]
        for name, key in zip(KEYS, keys, strict=True):
            edges = np.flatnonzero(np.diff(np.concatenate([[0], key, [0]])) != 0)
            runs = np.diff(edges)[key[edges[:-1]] != 0]  # runs of one held value
            holds[name] += list(runs)
        lapsed += int(np.sum(t.alive & (still(when, len(t.actions)) >= LAPSE)))
        alive += int(t.alive.sum())
        pressed = fire_presses(keys)
        presses += len(pressed)
        open_presses += int(t.vulnerable[pressed].sum())
        frames += len(t.actions)
    out = {"reaction_ms": _ms(reactions, 50)}
    for name, runs in holds.items():
        out[f"{name}_hold_median_ms"], out[f"{name}_hold_p90_ms"] = _ms(runs, 50), _ms(runs, 90)
    out["lapse_share"] = lapsed / max(alive, 1)
    out["fires_per_s"] = presses / (frames / FPS)
    out["fires_open_share"] = open_presses / presses if presses else None
    return out


def likeliest_policy(trials: list[Trial], role: str) -> str:
    """The library policy of `role` under which the person's actions (while alive) are likeliest."""
    obs = np.concatenate([t.alive_obs for t in trials])
    actions = np.concatenate([t.alive_actions for t in trials])
    scores = {}
    for key in library.keys(role):
        policy = networks.load(key)
        probs = batch_probs(policy, in_view(obs, policy.view))[np.arange(len(actions)), actions]
        scores[key] = float(np.mean(np.log(np.maximum(probs, 1e-12))))
    return max(scores, key=scores.get)


def simulated(people: dict[str, tuple[str, str]], role: str, seeds: int = FIT_SEEDS) -> dict[str, np.ndarray]:
    """For each person (policy, agent), the (FIT_SKILLS, STATISTICS) means and standard deviations
    of stand-ins of that policy at each skill, playing with that agent (played once for each)."""
    kinds = list(dict.fromkeys(people.values()))
    teams = []
    for policy, agent in kinds:
        for skill in FIT_SKILLS:
            person = f"human({policy},skill={skill:g})"
            teams.append((person, agent) if role == "bait" else (agent, person))
    kills, played, opened = play_teams(list(map(seats_of, teams)), list(range(seeds)), record=True)
    seat = ROLES.index(role)
    tables = []
    for p in range(len(kinds)):
        table = np.zeros((len(FIT_SKILLS), 2, len(STATISTICS)))
        for j in range(len(FIT_SKILLS)):
            row = p * len(FIT_SKILLS) + j
            games = [
                statistics(played[row, g, :, seat], np.flatnonzero(opened[row, g]), kills[row, g])
                for g in range(seeds)
            ]
            values = np.array([[game[k] for k in STATISTICS] for game in games])
            table[j] = values.mean(axis=0), values.std(axis=0, ddof=1)
        tables.append(table)
    return {name: tables[kinds.index(kind)] for name, kind in people.items()}


def fit(paths: list[Path], role: str) -> dict[str, dict]:
    """Each participant's stand-in, from their recordings of `role`: the likeliest library policy,
    and the skill whose simulated stand-ins (that policy, with the participant's agent) come
    nearest the participant's statistics (in standard errors of the participant's mean, at skills
    interpolated between FIT_SKILLS); with the statistics, the shortest press and the partner name."""
    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if not paths:
        raise UsageError("RECORDINGS", "(none)", "give at least one recording")
    trials: dict[str, list[tuple[Path, Trial]]] = {}
    for path in map(Path, paths):
        try:
            trial = read_trial(path, role)
        except UsageError:
            raise
        except (OSError, ValueError) as error:
            raise Failure(f"{path}: unreadable recording ({error}); nothing fitted") from None
        participant = str(study_record(path).get("participant") or path.name.removesuffix(".tsflog"))
        trials.setdefault(participant, []).append((path, trial))
    people = {}
    for name, own in trials.items():
        agents = Counter(t.agent for _, t in own)
        people[name] = (likeliest_policy([t for _, t in own], role), agents.most_common(1)[0][0])
    simulation = simulated(people, role)
    fine = np.linspace(0.0, 1.0, 51)
    designs: dict = {}
    out = {}
    for name, own in trials.items():
        games = [statistics(t.actions, t.opened, t.kills_per_minute) for _, t in own]
        observed = {k: float(np.mean([g[k] for g in games])) for k in (*STATISTICS, "hold_ms")}
        means, spreads = simulation[name][:, 0], simulation[name][:, 1]
        at = [np.interp(fine, FIT_SKILLS, means[:, k]) for k in range(len(STATISTICS))]
        sd = [
            np.interp(fine, FIT_SKILLS, spreads[:, k]) / np.sqrt(len(games)) + 1e-9
            for k in range(len(STATISTICS))
        ]
        distance = sum(((observed[k] - at[i]) / sd[i]) ** 2 for i, k in enumerate(STATISTICS))
        skill = float(fine[int(np.argmin(distance))])
        policy, agent = people[name]
        parameters, errors = parameters_of([t for _, t in own], policy, agent, role, designs)
        out[name] = {
            "partner": human_with(policy, parameters, skill=skill),
            "policy": policy,
            "skill": skill,
            "parameters": parameters,
            "errors": errors,
            "agent": agent,
            "statistics": observed,
            "traits": traits([t for _, t in own]),
            "recordings": [str(p) for p, _ in own],
        }
    return out


# ---------------------------------------------------------------- the model's parameters, fitted

LAGS = (0, 4, 8, 12)  # frames: where the policy's likelihood of the keys is read (signature)
DESIGN = 96  # simulated stand-ins per (policy, agent), their parameters drawn at random
DESIGN_GAMES = 2  # games each
DESIGN_SEED = 30  # the generator of the design's parameters
# The parameters the regression estimates, and the range the design draws each from (ours: a bit
# wider than novice to practised). The turn and thrust keys' hold is read directly off the keys
# (shortest_runs): they change often enough that the floor shows. The fire key's runs are the
# policy's as much as the person's (a policy that rarely wants a short gap never shows the
# person's), so its burst and gap are estimated, the shortest runs among the signature.
ESTIMATED = {
    "reaction_ms": (150.0, 330.0),
    "look_ms": (67.0, 400.0),
    "lapses": (0.0, 8.0),
    "slip": (0.0, 0.1),
    "foresight": (0.0, 1.0),
    "fire_ms": (33.0, 333.0),
    "fire_gap_ms": (33.0, 200.0),
}
HOLDS = ("hold_ms", "fire_ms", "fire_gap_ms")  # shortest_runs' names
HOLD_RANGE = (33.0, 167.0)  # the design's turn and thrust hold

SIGNATURE = (
    *(f"likelihood_{lag}" for lag in LAGS),
    "key_changes_per_s",
    "turn_reversals",
    "frozen_per_minute",
    "frozen_share",
    "fires_per_s",
    "fires_open_share",
    "kills_per_minute",
    *HOLDS,
)


def signature(actions: np.ndarray, obs: np.ndarray, kills_per_minute: float, policy) -> np.ndarray:
    """What one game's keys say of the person's parameters (SIGNATURE): the mean log-likelihood of
    their keys under the policy on the state of `lag` frames before, moved to now by the forward
    model (the person's own ship by their keys), over the frames alive and not in a long run; key
    changes per second; the share of turn changes straight from left to right or back (slips make
    them); runs of 0.5 s or more without a change (ship alive) per minute, and their share of the
    time; fire presses per second, the share of them made while the fortress is vulnerable;
    kills/min; the holds (shortest_runs). Which parameter each speaks for is the regression's to
    find (regress)."""
    frames = len(actions)
    keys = np.array(split_action(actions))
    when = changes(keys)
    alive = obs[:, ob.SELF + ob.ALIVE] > 0.5
    frozen = (still(when, frames) >= FROZEN) & alive
    rules = rules_of(GameConfig())
    likelihoods = []
    for lag in LAGS:  # over the frames alive and not frozen: a lapse's frames say nothing of the lag
        t = np.arange(lag, frames)
        ring = np.zeros((len(t), HISTORY), np.int64)  # predict reads keys at (0 - lag + k) % HISTORY
        if lag:
            back = np.arange(-lag, 0)
            ring[:, back % HISTORY] = actions[t[:, None] + back[None]]
        moved = predict(obs[t - lag], np.full(len(t), lag), np.zeros(len(t), np.int64), ring, 0, rules)
        probs = batch_probs(policy, in_view(moved, policy.view))[np.arange(len(t)), actions[t]]
        likelihoods.append(float(np.mean(np.log(np.maximum(probs, 1e-9))[alive[t] & ~frozen[t]])))
    turns = keys[0][np.flatnonzero(np.diff(keys[0]) != 0)[:, None] + [0, 1]]  # (changes, before/after)
    reversals = float(np.mean(turns.min(axis=1) > 0)) if len(turns) else 0.0  # left <-> right at once
    starts = np.flatnonzero(np.diff(np.concatenate([[0], frozen.astype(np.int64)])) == 1)
    pressed = fire_presses(keys)
    open_share = obs[pressed, ob.FORTRESS + ob.F_VULNERABLE] > 0.0
    seconds = frames / FPS
    return np.array(
        [
            *likelihoods,
            len(when) / seconds,
            reversals,
            len(starts) / seconds * 60.0,
            float(frozen.mean()),
            len(pressed) / seconds,
            float(open_share.mean()) if len(pressed) else 0.0,
            kills_per_minute,
            *shortest_runs([actions]).values(),
        ]
    )


def design(policy: str, agent: str, role: str) -> tuple[np.ndarray, np.ndarray]:
    """DESIGN stand-ins of `policy` with `agent`, each parameter of ESTIMATED and the hold drawn
    uniformly in its range, DESIGN_GAMES games each: their (DESIGN, ESTIMATED) parameters and
    (DESIGN, SIGNATURE) mean signatures."""
    rng = np.random.default_rng(DESIGN_SEED)
    ranges = {**ESTIMATED, "hold_ms": HOLD_RANGE}
    drawn = [{name: rng.uniform(*bounds) for name, bounds in ranges.items()} for _ in range(DESIGN)]
    teams = [
        (human_with(policy, d), agent) if role == "bait" else (agent, human_with(policy, d)) for d in drawn
    ]
    played_teams = list(map(seats_of, teams))
    kills, played, _, obs = play_teams(played_teams, list(range(DESIGN_GAMES)), record=True, world_of=role)
    actions = played[..., ROLES.index(role)]
    inner = networks.load(policy)
    signatures = np.array(
        [
            np.mean(
                [signature(a, o, k, inner) for a, o, k in zip(actions[i], obs[i], kills[i], strict=True)], 0
            )
            for i in range(DESIGN)
        ]
    )
    return np.array([[d[name] for name in ESTIMATED] for d in drawn]), signatures


def human_with(policy: str, parameters: dict[str, float], **settings: float) -> str:
    """The human(...) partner of a policy played with these parameters (PARAMETERS' order), after
    other settings (skill, input_ms) where given."""
    values = [f"{name}={value:g}" for name, value in settings.items()]
    values += [f"{name}={parameters[name]:.3g}" for name in PARAMETERS if name in parameters]
    return f"human({policy},{','.join(values)})"


def regress(drawn: np.ndarray, signatures: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter estimated from a signature by a ridge regression fitted on the design (the
    statistic-to-parameter map, calibrated by simulation), clipped to its range: the estimates at
    `observed` and each parameter's error, the root mean square of its leave-one-out residuals."""
    centre, scale = signatures.mean(0), signatures.std(0) + 1e-9
    x = np.column_stack([np.ones(len(drawn)), (signatures - centre) / scale])
    ridge = np.eye(x.shape[1]) * RIDGE
    ridge[0, 0] = 0.0
    inverse = np.linalg.inv(x.T @ x + ridge)
    coefficients = inverse @ x.T @ drawn
    leverage = np.einsum("ij,jk,ik->i", x, inverse, x)
    residuals = (drawn - x @ coefficients) / (1.0 - leverage)[:, None]
    low, high = np.array(list(ESTIMATED.values())).T
    estimate = np.concatenate([[1.0], (observed - centre) / scale]) @ coefficients
    return np.clip(estimate, low, high), np.sqrt(np.mean(residuals**2, axis=0))


RIDGE = 1.0  # the regression's ridge, in units of the standardised signature (ours)


def parameters_of(own: list[Trial], policy: str, agent: str, role: str, designs: dict) -> tuple[dict, dict]:
    """A participant's parameters: the turn and thrust hold read off their keys, the rest by the
    regression over the design of their policy and agent (made once for each, kept in `designs`);
    and the regression's error of each."""
    if (policy, agent) not in designs:
        designs[policy, agent] = design(policy, agent, role)
    drawn, signatures = designs[policy, agent]
    inner = networks.load(policy)
    observed = np.mean([signature(t.actions, t.obs, t.kills_per_minute, inner) for t in own], 0)
    estimate, error = regress(drawn, signatures, observed)
    names = list(ESTIMATED)
    holds = shortest_runs([t.actions for t in own])
    return holds | dict(zip(names, estimate.tolist(), strict=True)), dict(
        zip(names, error.tolist(), strict=True)
    )


def write(directory: Path, role: str, fitted: dict[str, dict], command: str) -> Path:
    """DIR/stand_ins.json: the role, each participant's fit, and the command that made it."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / STAND_INS
    path.write_text(json.dumps({"role": role, "people": fitted, "command": command}, indent=1) + "\n")
    return path
