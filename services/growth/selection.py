"""Stage 6, the selection: per seat of ours, the greedy coverage selection (choice.select) on the
validation population's held-out cross-play, written to `selection.json`."""

from __future__ import annotations

import json

from services.growth import choice
from services.growth.choice import Grid
from services.growth.workspace import Workspace
from shared.files import write_json
from shared.game import other


def selection(ws: Workspace, held_out: dict[str, Grid]) -> dict[str, list[dict]]:
    """Per seat of ours, the greedy selection's steps on the validation population."""
    done = ws.out / "selection.json"
    if not done.exists():
        sides = ws.sides()
        record = {}
        for role, grid in held_out.items():
            grid = grid.only([p for p in grid.partners if sides[p] == "validation"])
            steps = choice.select(grid, int(ws.spec.selection["most"]), ws.spec.selection["gain"])
            record[other(role)] = steps
            last = steps[-1]
            size, room = len(last["library"]), last["headroom"]
            ws.say(f"selection, {other(role)} seat: {size} members, headroom {room:+.1%} on validation")
        write_json(done, record)
    return json.loads(done.read_text())
