"""The grown library's figures on the test population, computed from the run's files each time
(`summary.json`, `summary.md`): per seat of ours, the held-out oracle headroom and the best single
member beside the study library's, the selection's headroom curve, and each member's kills/min
with each partner group (± standard error over the group's partners); and the population's
competence: per seat and family, how many members have a teammate that scores with them."""

from __future__ import annotations

import json

import numpy as np

from services.growth import choice
from services.growth.choice import Grid
from services.growth.groups import competence, grouped
from services.growth.library import MEMBERS, merged_label
from services.growth.workspace import Workspace
from shared.files import write_json
from shared.game import ROLES, other

ABLE = 1.0  # kills/min with its best teammate: a member at least this good "can score" (issue 57)


def summary(
    ws: Workspace, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
) -> dict:
    """The figures of every seat of ours, written to summary.json and summary.md."""
    names = json.loads((ws.library_dir / MEMBERS).read_text())
    sides = ws.sides()
    record: dict = {"population": ws.spec.text_hash, "members": names, "seats": {}}
    for ours, steps in selection.items():
        grid = held_out[other(ours)]
        train, label = grouped(grouping[other(ours)], groups[other(ours)]["groups"])
        label = merged_label(ws, ours, label)  # the groups as the library's groups.json names them
        chosen = steps[-1]["library"]
        study = [c for c in grid.candidates if c in ws.spec.seats[ours].library]
        test = [p for p in grid.partners if sides[p] == "test"]
        people = [p for p in test if p.startswith("human(")]
        members = [p for p in test if p not in people]
        figures = {}
        for part, rows in (("members", members), ("stand-ins", people), ("both", test)):
            figures[part] = figures_on(grid.only(rows), chosen, study)
        assigned = choice.place(grid, train, label)
        record["seats"][ours] = {
            "curve": steps,
            "test": figures,
            "groups": group_table(chosen, grid, assigned, int(label.max()) + 1),
            "partners": {p: f"G{g + 1}" for p, g in zip(grid.partners, assigned.tolist(), strict=True)},
        }
    record["competence"] = population_competence(ws, grouping, held_out)
    write_json(ws.out / "summary.json", record)
    (ws.out / "summary.md").write_text(markdown(record))
    return record


def population_competence(ws: Workspace, grouping: dict[str, Grid], held_out: dict[str, Grid]) -> dict:
    """Per partner seat and family: the members, how many score at least ABLE kills/min with their
    best teammate (the best of the candidates it played with, over seeds), and the median of that
    best: what training a population to competence changes (the grouping's grid holds the training
    members, the held-out one the validation and test members)."""
    rows = json.loads((ws.out / "population.json").read_text())["members"]
    out: dict = {}
    for role in ROLES:
        best = competence(grouping[role]) | competence(held_out[role])
        families: dict[str, list[float]] = {}
        for row in rows[role]:
            if row["name"] in best:
                families.setdefault(row["family"], []).append(best[row["name"]])
        out[role] = {
            family: {
                "members": len(values),
                "able": sum(v >= ABLE for v in values),
                "median": round(float(np.median(values)), 3),
            }
            for family, values in families.items()
        }
    return out


def figures_on(grid: Grid, chosen: list[str], study: list[str]) -> dict:
    """A library's held-out oracle headroom on `grid`'s partners, its best single member, and the
    study library's (its policies among the candidates) on the same partners."""
    kills, study_kills = grid.columns(chosen), grid.columns(study)
    single, mean = choice.best_single(kills)
    study_single, study_mean = choice.best_single(study_kills)
    return {
        "partners": len(grid.partners),
        "headroom": round(choice.headroom(kills), 4),
        "oracle": round(choice.oracle(kills), 4),
        "best_single": chosen[single],
        "best_single_mean": round(mean, 4),
        "study_best_single": study[study_single],
        "study_best_single_mean": round(study_mean, 4),
        "study_headroom": round(choice.headroom(study_kills), 4),
    }


def group_table(chosen: list[str], grid: Grid, assigned: np.ndarray, groups: int) -> list[dict]:
    """Each member's kills/min (± s.e. over the group's partners) with each partner group."""
    out = []
    for name in chosen:
        column = grid.columns([name])[:, 0].mean(axis=1)
        row = {"member": name}
        for j in range(groups):
            values = column[assigned == j]
            row[f"group {j + 1}"] = round(float(values.mean()), 3) if len(values) else None
            row[f"group {j + 1} se"] = (
                round(float(values.std(ddof=1) / np.sqrt(len(values))), 3) if len(values) > 1 else None
            )
        out.append(row)
    return out


def markdown(summary: dict) -> str:
    """The run's figures as a page: per seat, the test population's headroom and best single member
    beside the study library's, and the selection's headroom curve."""
    lines = [
        "# The grown library",
        "",
        f"Population spec {summary['population']}; every partner is simulated.",
        "",
    ]
    for ours, seat in summary["seats"].items():
        lines += [
            f"## The {ours} seat",
            "",
            "| test partners | n | headroom | grown: best single | study: best single | study: headroom |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for label, f in seat["test"].items():
            lines.append(
                f"| {label} | {f['partners']} | {f['headroom']:+.1%} | "
                f"{f['best_single']} {f['best_single_mean']:.2f} | "
                f"{f['study_best_single']} {f['study_best_single_mean']:.2f} | {f['study_headroom']:+.1%} |"
            )
        lines += [
            "",
            "Selection on the validation population (headroom against library size):",
            "",
            "| size | added | headroom |",
            "| --- | --- | --- |",
        ]
        for i, step in enumerate(seat["curve"]):
            lines.append(f"| {i + 1} | {step['library'][-1]} | {step['headroom']:+.1%} |")
        lines.append("")
    if "competence" in summary:  # older runs' summary.json have none
        lines += [
            "## The population's competence",
            "",
            f"Members whose best teammate scores at least {ABLE:g} kill/min with them, and the median "
            "best teammate's kills/min, by partner seat and family:",
            "",
            "| partners | family | members | able to score | median best |",
            "| --- | --- | --- | --- | --- |",
        ]
        for role, families in summary["competence"].items():
            for family, c in families.items():
                lines.append(f"| {role} | {family} | {c['members']} | {c['able']} | {c['median']:.2f} |")
        lines.append("")
    return "\n".join(lines)
