"""The skill table: every library teammate of one seat with calibrated human-like stand-ins of
each style and skill, beside P.

P measures library pairs only, so it knows nothing about what works with a slow, lapsing or
novice partner. Here a partner is `human(K,skill=S)` (population/human_like.py, docs/humans.md): the
library policy K of the other role (its style) played by a simulated hand of skill S (novice,
typical, practised). Each (partner, teammate) cell is the mean kills/min over seeded one-minute
games (seeds 0..games-1, as P's), with its standard error; the games are played as the lanes of
batches (evaluate.play_teams). The table is bound to the libraries and rules it was measured with,
as P is.
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.adapter.core import Window
from services.adapter.skill import EVERY, FEATURES, LEVELS, Keys, SkillModel
from services.agent import library
from services.agent.policy import end_round_batch
from services.evaluation.evaluate import LANES, batches, play_games, play_teams, setup
from services.population.adaptive import AdapterConfig
from services.population.seat import SeatSpec, seats_of
from services.sim import observation as ob
from services.table.table import stderr
from shared.errors import UsageError
from shared.game import ROLES, GameConfig
from shared.processes import end_with_parent
from shared.provenance import provenance

VERSION = 1
SKILLS = LEVELS[:-1]  # human_like.SKILLS, in order of practice
MODEL_SEEDS = tuple(range(64, 76))  # 4 people x 3 trials, past the evaluation's 0-63 and the table's


def stand_in(style: str, skill: str) -> str:
    """The partner name of `style` (a library key) played by a hand of `skill`."""
    return f"human({style},skill={skill})"


@dataclass(frozen=True)
class SkillTable:
    """Kills/min of each teammate (our seat, `role`) with each stand-in (style x skill)."""

    role: str
    teammates: tuple[str, ...]
    styles: tuple[str, ...]
    skills: tuple[str, ...]
    games: int
    results: dict[str, dict[str, list[float]]]  # partner name -> teammate -> kills/min per seed
    library: str = field(default_factory=library.manifest_hash)
    config: str = field(default_factory=lambda: GameConfig().hash())
    version: int = VERSION

    @property
    def partners(self) -> list[str]:
        return [stand_in(style, skill) for style in self.styles for skill in self.skills]

    def mean(self, partner: str, teammate: str) -> float:
        return statistics.fmean(self.results[partner][teammate])

    def stderr(self, partner: str, teammate: str) -> float:
        return stderr(self.results[partner][teammate])

    def best(self, partner: str) -> str:
        """The best response to `partner`: the teammate of the highest mean."""
        return max(self.teammates, key=lambda t: self.mean(partner, t))

    def overall(self, teammate: str) -> float:
        """A teammate's mean over every stand-in (each weighted alike)."""
        return statistics.fmean(self.mean(p, teammate) for p in self.partners)

    def best_static(self) -> str:
        """The best single teammate over every stand-in."""
        return max(self.teammates, key=self.overall)

    def gain(self, partner: str, teammate: str, than: str) -> tuple[float, float]:
        """Mean and standard error of `teammate` minus `than` with `partner`, paired by seed."""
        a, b = self.results[partner][teammate], self.results[partner][than]
        diff = [x - y for x, y in zip(a, b, strict=True)]
        return statistics.fmean(diff), stderr(diff)

    def held_out(self, than: dict[str, str] | None = None) -> float:
        """The headroom without the choice's luck: the best response and the best static teammate
        chosen on one half of the seeds (even, odd), scored on the other, both ways; the mean over
        stand-ins of best minus static (or minus `than`: partner -> teammate, chosen elsewhere)."""
        folds = [range(0, self.games, 2), range(1, self.games, 2)]
        gains = []
        for chosen, scored in (folds, folds[::-1]):

            def mean(p: str, t: str, seeds: range) -> float:
                return statistics.fmean(self.results[p][t][i] for i in seeds)

            static = max(
                self.teammates, key=lambda t: statistics.fmean(mean(p, t, chosen) for p in self.partners)
            )
            for p in self.partners:
                best = max(self.teammates, key=lambda t: mean(p, t, chosen))
                other = than[p] if than else static
                gains.append(mean(p, best, scored) - mean(p, other, scored))
        return statistics.fmean(gains)

    def extend(self, other: SkillTable) -> SkillTable:
        """This table with `other`'s teammates as more columns (same role, stand-ins and seeds),
        bound to the libraries `other` was measured with."""
        if (other.role, other.styles, other.skills, other.games) != (
            self.role,
            self.styles,
            self.skills,
            self.games,
        ):
            raise ValueError("the tables differ in role, styles, skills or games")
        results = {p: self.results[p] | other.results[p] for p in self.partners}
        teammates = self.teammates + other.teammates
        return SkillTable(
            self.role, teammates, self.styles, self.skills, self.games, results, other.library, other.config
        )

    def save(self, path: Path) -> None:
        record = {
            "version": self.version,
            "library": self.library,
            "config": self.config,
            "role": self.role,
            "games": self.games,
            "seeds": list(range(self.games)),
            "teammates": list(self.teammates),
            "styles": list(self.styles),
            "skills": list(self.skills),
            "mean": {p: {t: round(self.mean(p, t), 6) for t in self.teammates} for p in self.partners},
            "stderr": {p: {t: round(self.stderr(p, t), 6) for t in self.teammates} for p in self.partners},
            "results": self.results,
            "provenance": provenance(self.library, "self") | {"config": self.config},
        }
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1) + "\n")

    @classmethod
    def load(cls, path: Path) -> SkillTable:
        record = json.loads(Path(path).read_text())
        if record.get("version") != VERSION:
            raise ValueError(f"{path}: skill table format {record.get('version')}, expected {VERSION}")
        fields = ("role", "teammates", "styles", "skills", "games", "results", "library", "config")
        return cls(**{k: tuple(record[k]) if isinstance(record[k], list) else record[k] for k in fields})


def _play(teams: list[tuple[str, str]], games: int) -> list[list[float]]:
    return play_teams(list(map(seats_of, teams)), list(range(games))).tolist()


def measure(
    role: str,
    teammates: list[str],
    styles: list[str],
    skills: tuple[str, ...] = SKILLS,
    games: int = 20,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> SkillTable:
    """Play every (stand-in, teammate) pair over seeds 0..games-1, `workers` batches at once;
    `progress(games done, games in all)` is told as each batch comes back."""
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}; expected one of {ROLES}")
    partners = [stand_in(style, skill) for style in styles for skill in skills]
    pairs = [(p, t) for p in partners for t in teammates]
    teams = [(t, p) if role == "bait" else (p, t) for p, t in pairs]
    chunks = batches(teams, workers, max(1, LANES // games))  # a game is the same in any batch
    told = progress or (lambda done, total: None)
    played: list[list[float]] = []
    told(0, len(teams) * games)
    with ProcessPoolExecutor(workers, initializer=end_with_parent) if workers > 1 else nullcontext() as pool:
        rows = pool.map(_play, chunks, [games] * len(chunks)) if pool else (_play(c, games) for c in chunks)
        for chunk in rows:  # in the chunks' order, as each comes back
            played += chunk
            told(len(played) * games, len(teams) * games)
    results: dict[str, dict[str, list[float]]] = {p: {} for p in partners}
    for (p, t), row in zip(pairs, played, strict=True):
        results[p][t] = row
    return SkillTable(role, tuple(teammates), tuple(styles), tuple(skills), games, results)


def summary(table: SkillTable, p_best: dict[str, str]) -> str:
    """Markdown: each stand-in's best response (and its gain over the best static teammate, paired
    by seed) beside P's best response to its style (`p_best`: style -> teammate) and what that
    one scores here; then the headroom over the best static teammate and over P's choice."""
    static = table.best_static()
    lines = [
        f"| style | skill | best {table.role} | best static {static} | best - {static} | P's best | it here |"
        "",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    chosen_by_p: dict[str, str] = {}
    for style in table.styles:
        for skill in table.skills:
            partner = stand_in(style, skill)
            best, p = table.best(partner), p_best.get(style, "")
            gain, se = table.gain(partner, best, static)
            here = table.mean(partner, p) if p in table.teammates else math.nan
            if p in table.teammates:
                chosen_by_p[partner] = p
            best_text = f"{best} {table.mean(partner, best):.2f} ± {table.stderr(partner, best):.2f}"
            lines.append(
                f"| {style} | {skill} | {best_text} | {table.mean(partner, static):.2f} "
                f"| {gain:+.2f} ± {se:.2f} | {p or '-'} | {here:.2f} |"
            )
    headroom = statistics.fmean(table.mean(p, table.best(p)) - table.mean(p, static) for p in table.partners)
    lines += [
        "",
        f"Best static {table.role}: {static}, {table.overall(static):.2f} kills/min over every stand-in. "
        f"Headroom (mean best response minus it): {headroom:.2f} chosen after the fact, "
        f"{table.held_out():.2f} chosen on half the seeds and scored on the other half.",
    ]
    if len(chosen_by_p) == len(table.partners):
        over_p = table.held_out(chosen_by_p)
        lines[-1] += f" Held-out best response minus P's best response to the style: {over_p:.2f}."
    return "\n".join(lines) + "\n"


def skill_model(
    table: SkillTable,
    window: int = AdapterConfig.window,
    seeds: tuple = MODEL_SEEDS,
    progress: Callable[[int, int], None] | None = None,
) -> SkillModel:
    """The adapter's skill model for the table's seat: the table's means, and each level's FEATURES
    per style (mean and standard deviation over the windows the adapter reads: every EVERY frames
    from the end of its warm-up, of games of each stand-in and of the library policy itself, with
    the table's best static teammate, over `seeds`); `progress(styles done, styles)` as it goes."""
    payoff = setup(table.role).payoff
    told = progress or (lambda done, total: None)
    if set(payoff.partners) != set(table.styles) or not set(payoff.ours) <= set(table.teammates):
        raise UsageError("--table", table.role, "its styles and teammates are not the libraries' in use")
    teammate, first = table.best_static(), AdapterConfig(window=window).warmup_frames
    mean = np.zeros((len(payoff.partners), len(LEVELS), len(FEATURES)))
    sd = np.zeros_like(mean)
    for i, style in enumerate(payoff.partners):  # one batch per style
        told(i, len(payoff.partners))
        names = [stand_in(style, skill) for skill in SKILLS] + [style]
        games = [(SeatSpec.parse(name), SeatSpec.parse(teammate), seed) for name in names for seed in seeds]
        played = play_games(games, table.role, record=True, score="library")
        scores, states = np.stack([o.scores for o in played]), np.stack([o.values for o in played])
        actions = np.stack([o.actions for o in played])
        means, keys, read = Window(len(games), len(payoff.partners), window), Keys(len(games), window), []
        for frame in range(actions.shape[1]):  # as AdapterLanes.update reads them
            keys.push(actions[:, frame], states[:, frame, ob.SELF + ob.ALIVE] > 0.5)
            pushed = np.flatnonzero(~end_round_batch(states[:, frame].astype(np.float32), "world")[0])
            means.push(pushed, scores[pushed, frame])
            if frame + 1 >= first and (frame + 1) % EVERY == 0:
                read.append(keys.features(means.means().max(axis=1)))
        windows = np.stack(read, axis=1).reshape(len(names), len(seeds) * len(read), len(FEATURES))
        mean[i], sd[i] = windows.mean(axis=1), windows.std(axis=1)
    told(len(payoff.partners), len(payoff.partners))
    values = np.array(
        [[[table.mean(stand_in(s, k), t) for t in payoff.ours] for k in SKILLS] for s in payoff.partners]
    )
    return SkillModel(
        table.role, payoff.partners, payoff.ours, window, values, mean, sd, tuple(seeds), table.library
    )
