"""The search (search.py) on a grown run that exists, without retraining anything: `tsf library
search`. Our seat's rule is searched over the run's training members, grouped as the run grouped
them (its records: run-population.json, run-groups.json), then each study's best setting is
measured on the run's test split (members and their stand-ins, held_out.py) against fixed
references: the run's best single member (GS1 or GB1 for the shipped run) and the study library's
best static on the test split (as the run's summary names it), in kills/min and %, with the
partner as the unit (a one-sided paired t-test over the partners' means) and the game (over every
partner and seed). `by group` plays each test partner its own group's best setting: what an agent
that knew the group would get from the search.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.agent.scripted import SCRIPTED
from services.evaluation import held_out
from services.evaluation.evaluate import play_teams
from services.evaluation.results import percent, percent_text
from services.evaluation.team import paired_tests
from services.growth.search import SPACES, WHOLE, best, curve, plan_of, scorer, stem, tune
from services.population.families import RULE_FAMILIES
from services.population.seat import seats_of
from shared.errors import UsageError
from shared.files import write_json
from shared.game import other

BY_GROUP = "by group"  # each test partner with its group's best setting
PARTS = ("members", "stand-ins", "both")
RECORDS = ("population", "groups", "summary")  # the run's records the search reads


def references(ours: str, run: Path) -> dict[str, str]:
    """The fixed references of seat `ours`: the run's best single member, by its key where the run's
    library names it (GS1), and the study library's best static on the test split."""
    summary = json.loads((run / "run-summary.json").read_text())
    test = summary["seats"][ours]["test"]["both"]
    keys = {name: key for key, name in summary["members"].items()}
    return {
        keys.get(test["best_single"], test["best_single"]): test["best_single"],
        "study best": test["study_best_single"],
    }


def check_run(run: Path) -> None:
    """A UsageError unless `run` holds a grown run's records (the shipped grown library does)."""
    missing = [f"run-{n}.json" for n in RECORDS if not (run / f"run-{n}.json").is_file()]
    if missing:
        raise UsageError("--run", run, f"is no grown run's library (no {', '.join(missing)})")


def families(ours: str) -> list[str]:
    """The rule families our seat's search can tune: the seat's own rule first (the growth's), then
    the other scripted rules of that seat that have a search space (the bait's orbit)."""
    rules = [k for k, policy in SCRIPTED.items() if policy.role == ours and k in SPACES]
    return [RULE_FAMILIES[ours], *(k for k in rules if k != RULE_FAMILIES[ours])]


def search_run(
    ours: str, run: Path, out: Path, trials: int, seeds: int, seed: int, family: str | None = None
) -> dict:
    """Our seat's rule (`family`, default the seat's own) searched over the run's training members
    (written to OUT/search-SEAT.json as it goes, resumed from there; search-SEAT-FAMILY.json for a
    family other than the seat's own), then measured on its test split (OUT/measured-SEAT....json)."""
    family = family or RULE_FAMILIES[ours]
    name = stem(ours, family)
    groups = json.loads((run / "run-groups.json").read_text())[other(ours)]["groups"]
    plan = plan_of(family, groups, trials, seeds, seed)
    out.mkdir(parents=True, exist_ok=True)
    record = tune(plan, scorer(ours, plan.partners, seeds), out / f"search-{name}.json")
    measured = measure(ours, run, best(record), seeds)
    result = {"seat": ours, "trials": len(record["trials"]), "best": best(record), "measured": measured}
    result["curves"] = {s: curve(record, s) for s in record["studies"]}
    write_json(out / f"measured-{name}.json", result)
    return result


def measure(ours: str, run: Path, found: dict[str, dict], seeds: int) -> dict:
    """Each study's best setting, the references and `by group` on the run's test split: per part,
    kills/min and the difference from each reference (partner and game as the unit)."""
    partners = held_out.test_partners(other(ours), run)
    refs = references(ours, run)
    columns = list(dict.fromkeys([*(f["name"] for f in found.values()), *refs.values()]))
    teams = [seats_of((p, c) if ours == "shooter" else (c, p)) for p in partners for c in columns]
    kills = play_teams(teams, list(range(seeds))).reshape(len(partners), len(columns), seeds)
    rows = {study: kills[:, columns.index(f["name"])] for study, f in found.items()}
    rows |= {label: kills[:, columns.index(name)] for label, name in refs.items()}
    group_of = [found.get(g, found[WHOLE])["name"] for g in partners.values()]
    rows[BY_GROUP] = np.array([kills[i, columns.index(n)] for i, n in enumerate(group_of)])
    parts = {
        "members": np.array([held_out.PARTS["members"](p) for p in partners]),
        "stand-ins": np.array([held_out.PARTS["stand-ins"](p) for p in partners]),
    }
    parts["both"] = np.ones(len(partners), bool)
    return {
        "references": refs,
        "partners": {part: int(where.sum()) for part, where in parts.items()},
        "teammates": {
            label: {
                part: _compared(row[where], [rows[r][where] for r in refs]) for part, where in parts.items()
            }
            for label, row in rows.items()
        },
    }


def _compared(row: np.ndarray, refs: list[np.ndarray]) -> dict:
    """A teammate's (partners, seeds) kills/min on one part: its mean, and against each reference
    the difference in kills/min and %, and the one-sided p that it is better, with the partner as
    the unit and with the game."""
    mean = float(row.mean())
    out: dict = {"kills": round(mean, 4), "against": []}
    for ref in refs:
        base = float(ref.mean())
        share = percent(mean - base, base)  # None: not defined, where the reference scores 0
        by_partner = paired_tests(row.mean(axis=1) - ref.mean(axis=1))
        by_game = paired_tests((row - ref).ravel())
        out["against"].append(
            {
                "difference": round(mean - base, 4),
                "percent": None if share is None else round(share, 1),
                "p_partners": round(by_partner["p_superior"], 4),
                "p_games": round(by_game["p_superior"], 4),
            }
        )
    return out


def markdown(result: dict) -> str:
    """The seat's search as tables: each study's best setting with its value on the training
    partners, and every teammate on the test split against the references."""
    measured, refs = result["measured"], list(result["measured"]["references"])
    family = result["best"][WHOLE]["name"].partition("(")[0]
    n = measured["partners"]
    lines = [
        f"## Our {result['seat']} seat's rule tuned by search ({family}, {result['trials']} settings)",
        "",
        "| study | best setting | kills/min, training partners |",
        "| --- | --- | --- |",
        *(f"| {s} | `{b['name']}` | {b['value']:.2f} |" for s, b in result["best"].items()),
        "",
        f"On the test split ({n['members']} members, {n['stand-ins']} stand-ins): kills/min, and the "
        f"difference from {' and from '.join(refs)} "
        f"({', '.join(f'{k} = `{v}`' for k, v in measured['references'].items())}); "
        f"p: one-sided paired t-test against {refs[0]}, the partner as the unit / the game.",
        "",
        "| teammate | " + " | ".join(PARTS) + " | p (both), partners / games |",
        "| --- | " + " | ".join("---" for _ in PARTS) + " | --- |",
    ]
    for label, parts in measured["teammates"].items():
        cells = [_cell(parts[part]) for part in PARTS]
        first = parts["both"]["against"][0]
        lines.append(
            f"| {label} | {' | '.join(cells)} | {first['p_partners']:.3f} / {first['p_games']:.3f} |"
        )
    return "\n".join([*lines, ""])


def _cell(compared: dict) -> str:
    against = " / ".join(percent_text(a["percent"]) for a in compared["against"])
    return f"{compared['kills']:.2f} ({against})"
