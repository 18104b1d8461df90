"""Stage 3, the groups: each seat's training members grouped by what works with them
(choice.groups, over the grouping cross-play), written to `groups.json`.

A member that scores under the spec's competence floor (`groups.floor`, kills/min) with every
candidate is kept out of the groups and listed apart (`left_out`, with its best): no teammate
serves it, and in the adapter its near-uniform likelihoods would only take posterior from the
groups that matter (issue 57's audit: 16-25 %)."""

from __future__ import annotations

import json

import numpy as np

from services.growth import choice
from services.growth.choice import Grid
from services.growth.workspace import Workspace
from shared.files import write_json


def groups(ws: Workspace, grouping: dict[str, Grid]) -> dict[str, dict]:
    """Each seat's competent training members grouped by what works with them (choice.groups)."""
    done = ws.out / "groups.json"
    if not done.exists():
        record = {}
        for role, grid in grouping.items():
            best = competence(grid)
            kept = grid.only([p for p in grid.partners if best[p] >= ws.spec.groups["floor"]])
            label, tried = choice.groups(
                kept, int(ws.spec.groups["most"]), ws.spec.groups["regret"], ws.spec.seed
            )
            members = [
                [p for p, g in zip(kept.partners, label, strict=True) if g == j]
                for j in range(label.max() + 1)
            ]
            left = {p: v for p, v in best.items() if p not in kept.partners}
            record[role] = {"groups": members, "tried": tried} | ({"left_out": left} if left else {})
            ws.say(
                f"groups of {role}s: {len(members)} ({', '.join(str(len(m)) for m in members)} members)"
                + (f", {len(left)} left out (under {ws.spec.groups['floor']:g} kills/min)" if left else "")
            )
        write_json(done, record)
    return json.loads(done.read_text())


def competence(grid: Grid) -> dict[str, float]:
    """Each partner's best candidate's mean kills/min: what the best teammate on offer gets."""
    means = grid.kills.mean(axis=2).max(axis=1)
    return {p: round(float(v), 4) for p, v in zip(grid.partners, means, strict=True)}


def grouped(grid: Grid, groups: list[list[str]]) -> tuple[Grid, np.ndarray]:
    """`grid` of the grouped partners alone (those left out of every group dropped), and each
    one's group, from the groups' member lists."""
    group = {m: j for j, members in enumerate(groups) for m in members}
    kept = grid.only([p for p in grid.partners if p in group])
    return kept, np.array([group[p] for p in kept.partners], np.int64)


def joined(label: np.ndarray, parts: list[list[int]]) -> np.ndarray:
    """Each label as its group's place among `parts` (groups joined, as lists of the labels they
    join: choice.merge's partition)."""
    index = {j: k for k, part in enumerate(parts) for j in part}
    return np.array([index[j] for j in label], np.int64)
