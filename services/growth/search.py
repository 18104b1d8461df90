"""Stage 6 of the growth, the search: rule teammates tuned by search, between the held-out
cross-play and the selection.

The rule grid is coarse: its best members sit at its edges, and some of a rule's settings (the
mirror's radius and rear tolerance) are never varied. The search tunes our seat's rule over its
whole continuous space (SPACES), for each partner group of the training population and for the
whole of it, with Optuna's TPE sampler (multivariate). Every setting is scored on every training
partner (`seeds` games each, in-process, as the lanes of one batch), so that a study of one group
learns from the settings the others asked for: a round asks each study (the whole population first,
then G1..) for one setting, plays the new ones, and tells every study the mean over its partners of
each partner's mean kills/min. Each study's best setting becomes a candidate: the held-out partners
play it (the spec's seeds, as every column of the held-out grids) and the selection chooses among
the grid, the study's policies, the responses and these.

SPACES also holds the bait seat's `orbit` (a rule that holds its radius and places itself by the
shooter): a spec's `search.families` names the families of each of our seats the growth searches
(each seat's own rule, RULE_FAMILIES, where it names none); `tsf library search --family` alike.

Resumable and deterministic: the trials are written after each round (`search-SEAT.json`), and a
round's studies are rebuilt from the written trials with a sampler seeded by (spec seed, round,
study), so that a resumed search asks what an unbroken one would have.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.evaluation.evaluate import play_teams
from services.growth.choice import Grid
from services.growth.crossplay import crossplay
from services.growth.workspace import Say, Workspace
from services.population.families import RULE_FAMILIES
from services.population.seat import seats_of
from shared.errors import UsageError
from shared.files import write_json
from shared.game import ROLES, other

# Each rule's searched settings: (lowest, highest, step); the step keeps a setting's name short.
SPACES = {
    "mirror": {
        "placed_distance": (2.0, 80.0, 0.5),
        "max_speed": (1.5, 10.0, 0.1),
        "aim_tolerance": (1.0, 25.0, 0.5),
        "radius": (150.0, 300.0, 1.0),
        "rear_tolerance": (5.0, 180.0, 1.0),  # 180: it fires from anywhere around the fortress
    },
    "circle": {"radius": (50.0, 200.0, 1.0), "speed": (0.5, 4.5, 0.05), "outside": (205.0, 300.0, 1.0)},
    "orbit": {  # `tsf library search --family orbit`: the bait that holds its radius, placed by the shooter
        "radius": (100.0, 200.0, 1.0),
        "speed": (0.0, 4.5, 0.05),
        "gain": (0.01, 0.3, 0.005),
        "damping": (0.0, 30.0, 0.5),
        "margin": (0.0, 40.0, 0.5),
        "place": (0.0, 4.0, 0.05),
        "lead": (-90.0, 90.0, 1.0),
        "clear": (0.0, 60.0, 0.5),
    },
}
WHOLE = "all"  # the study over the whole training population
Score = Callable[[list[str]], np.ndarray]  # setting names -> (settings, partners) mean kills/min


@dataclass(frozen=True)
class Plan:
    """One seat's search: the rule, the partners every setting is scored on, each study's partners
    (WHOLE first, then each group's), how many settings to play in all, seeds per pair."""

    family: str
    partners: tuple[str, ...]
    studies: dict[str, tuple[str, ...]]
    trials: int
    seeds: int
    seed: int

    def head(self) -> dict:
        """What a search file is bound to (a file of another plan is not resumed)."""
        return {
            "family": self.family,
            "partners": list(self.partners),
            "studies": {k: list(v) for k, v in self.studies.items()},
            "seeds": self.seeds,
            "seed": self.seed,
            "space": {k: list(v) for k, v in SPACES[self.family].items()},
        }


def plan_of(family: str, groups: list[list[str]], trials: int, seeds: int, seed: int) -> Plan:
    """A seat's plan over the training members of its partner `groups`."""
    partners = tuple(p for group in groups for p in group)
    studies = {WHOLE: partners} | {f"G{j + 1}": tuple(g) for j, g in enumerate(groups)}
    return Plan(family, partners, studies, trials, seeds, seed)


def name_of(family: str, setting: dict[str, float]) -> str:
    """A setting in the partner grammar: `mirror(placed_distance=8,...,radius=212)`."""
    return f"{family}({','.join(f'{k}={round(v, 4):g}' for k, v in setting.items())})"


def tune(plan: Plan, score: Score, path: Path, say: Say = print) -> dict:
    """The plan's search, resumed from `path` where it holds trials of the same plan, written there
    after each round; the record: the plan's head and every trial (setting, name, partners' means)."""
    record = {**plan.head(), "trials": []}
    if path.exists():
        record = json.loads(path.read_text())
        if {k: record.get(k) for k in plan.head()} != plan.head():
            raise UsageError("--out", path.parent, f"{path.name} is another search's; use a new --out")
    while len(record["trials"]) < plan.trials:
        turn = len({t["round"] for t in record["trials"]})
        asked = _ask(plan, record["trials"], turn)[: plan.trials - len(record["trials"])]
        kills = score([name_of(plan.family, s) for s in asked])
        for setting, row in zip(asked, kills, strict=True):
            name = name_of(plan.family, setting)
            record["trials"].append({"round": turn, "setting": setting, "name": name, "kills": _rounded(row)})
        write_json(path, record)
        tops = ", ".join(f"{k} {v['value']:.2f}" for k, v in best(record).items())
        say(f"search, {plan.family}: {len(record['trials'])}/{plan.trials} settings; best {tops}")
    return record


def _ask(plan: Plan, trials: list[dict], turn: int) -> list[dict[str, float]]:
    """Each study's next setting (duplicates once), from a study rebuilt from `trials`."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    space = SPACES[plan.family]
    dists = {k: optuna.distributions.FloatDistribution(lo, hi, step=st) for k, (lo, hi, st) in space.items()}
    asked: list[dict[str, float]] = []
    for i, (study, members) in enumerate(plan.studies.items()):
        rows = [plan.partners.index(p) for p in members]
        seed = int(np.random.SeedSequence([plan.seed, turn, i]).generate_state(1)[0])
        with warnings.catch_warnings():  # multivariate TPE is marked experimental
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            sampler = optuna.samplers.TPESampler(seed=seed, multivariate=True)
        made = optuna.create_study(direction="maximize", sampler=sampler, study_name=study)
        made.add_trials(
            [
                optuna.trial.create_trial(params=t["setting"], distributions=dists, value=_mean(t, rows))
                for t in trials
            ]
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            setting = {k: round(float(v), 4) for k, v in made.ask(dists).params.items()}
        if setting not in asked:
            asked.append(setting)
    return asked


def _mean(trial: dict, rows: list[int]) -> float:
    return float(np.mean([trial["kills"][r] for r in rows]))


def _rounded(row: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in row]


def best(record: dict) -> dict[str, dict]:
    """Each study's best trial so far: its name, setting and value (mean over its partners)."""
    out = {}
    for study, members in record["studies"].items():
        rows = [record["partners"].index(p) for p in members]
        top = max(record["trials"], key=lambda t: _mean(t, rows))
        out[study] = {"name": top["name"], "setting": top["setting"], "value": round(_mean(top, rows), 4)}
    return out


def curve(record: dict, study: str) -> list[float]:
    """A study's best value after each trial: the search's curve."""
    rows = [record["partners"].index(p) for p in record["studies"][study]]
    return np.maximum.accumulate([_mean(t, rows) for t in record["trials"]]).round(4).tolist()


def scorer(ours: str, partners: tuple[str, ...], seeds: int) -> Score:
    """Settings of our seat's rule scored on `partners`: each pair's mean over `seeds` games, every
    pair a lane of one batch (evaluate.play_teams)."""

    def score(names: list[str]) -> np.ndarray:
        teams = [seats_of((p, n) if ours == "shooter" else (n, p)) for n in names for p in partners]
        kills = play_teams(teams, list(range(seeds)))
        return kills.mean(axis=1).reshape(len(names), len(partners))

    return score


def found(record: dict) -> list[str]:
    """The settings the search found: each study's best, once each."""
    return list(dict.fromkeys(b["name"] for b in best(record).values()))


def stem(ours: str, family: str) -> str:
    """A search's file stem: our seat, and the family where it is not the seat's own rule
    (`search-bait.json`, `search-bait-orbit.json`)."""
    return ours if family == RULE_FAMILIES[ours] else f"{ours}-{family}"


def search(ws: Workspace, grouped: dict, held_out: dict[str, Grid]) -> dict[str, Grid]:
    """The held-out grids with a column for each setting the search found (the spec's `search`,
    each of our seat's families it names; without one, the grids as they are)."""
    if ws.spec.search is None:
        return held_out
    trials, seeds = ws.spec.search.trials, ws.spec.search.seeds
    settings: dict[str, list[str]] = {}
    with ws.playing([ws.population_dir, ws.responses_dir]):
        for role in ROLES:
            ours, settings[role] = other(role), []
            for family in ws.spec.search.of(ours):
                plan = plan_of(family, grouped[role]["groups"], trials, seeds, ws.spec.seed)
                path = ws.out / f"search-{stem(ours, family)}.json"
                settings[role] += found(tune(plan, scorer(ours, plan.partners, seeds), path, ws.say))
    partners = {r: list(g.partners) for r, g in held_out.items()}
    extra = crossplay(ws, "search-held-out", partners, settings)
    return {r: held_out[r].beside(extra[r]) for r in ROLES}
