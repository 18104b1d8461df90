"""Stage 3, the groups: each seat's training members grouped by what works with them
(choice.groups, over the grouping cross-play), written to `groups.json`."""

from __future__ import annotations

import json

import numpy as np

from services.growth import choice
from services.growth.choice import Grid
from services.growth.workspace import Workspace
from shared.files import write_json


def groups(ws: Workspace, grouping: dict[str, Grid]) -> dict[str, dict]:
    """Each seat's training members grouped by what works with them (choice.groups)."""
    done = ws.out / "groups.json"
    if not done.exists():
        record = {}
        for role, grid in grouping.items():
            label, tried = choice.groups(
                grid, int(ws.spec.groups["most"]), ws.spec.groups["regret"], ws.spec.seed
            )
            members = [
                [p for p, g in zip(grid.partners, label, strict=True) if g == j]
                for j in range(label.max() + 1)
            ]
            record[role] = {"groups": members, "tried": tried}
            ws.say(f"groups of {role}s: {len(members)} ({', '.join(str(len(m)) for m in members)} members)")
        write_json(done, record)
    return json.loads(done.read_text())


def labels(grid: Grid, groups: list[list[str]]) -> np.ndarray:
    """Each of `grid`'s partners' group, from the groups' member lists."""
    label = np.zeros(len(grid.partners), np.int64)
    for j, members in enumerate(groups):
        for m in members:
            label[grid.partners.index(m)] = j
    return label
