"""The groups stage: members no teammate serves are kept out of the groups and listed apart."""

from __future__ import annotations

import json

import numpy as np

from services.growth.choice import Grid
from services.growth.groups import competence, grouped, groups
from services.growth.workspace import Workspace
from services.population.families import SPEC, read


def _workspace(tmp_path, floor: float) -> Workspace:
    path = tmp_path / "population.toml"
    path.write_text(SPEC.read_text().replace("regret = 0.05", f"regret = 0.05, floor = {floor}", 1))
    return Workspace(read(path), tmp_path / "run", engine=None, say=lambda line: None)


def _grid() -> Grid:
    """Six partners, two candidates, two seeds: two that work with `a`, two with `b`, two with neither."""
    means = np.array([[6.0, 1.0], [5.0, 1.5], [1.0, 7.0], [1.5, 6.0], [0.2, 0.1], [0.0, 0.4]])
    return Grid(("p1", "p2", "p3", "p4", "p5", "p6"), ("a", "b"), np.repeat(means[:, :, None], 2, axis=2))


def test_members_under_the_floor_are_left_out_and_the_rest_grouped(tmp_path):
    ws = _workspace(tmp_path, 1.0)
    ws.out.mkdir()
    record = groups(ws, {"bait": _grid()})["bait"]
    assert sorted(sorted(g) for g in record["groups"]) == [["p1", "p2"], ["p3", "p4"]]
    assert record["left_out"] == {"p5": 0.2, "p6": 0.4}
    assert json.loads((ws.out / "groups.json").read_text())["bait"] == record


def test_without_a_floor_every_member_is_grouped_and_nothing_is_listed_apart(tmp_path):
    ws = _workspace(tmp_path, 0.0)
    ws.out.mkdir()
    record = groups(ws, {"bait": _grid()})["bait"]
    assert sorted(m for g in record["groups"] for m in g) == list(_grid().partners)
    assert "left_out" not in record


def test_grouped_keeps_the_grids_order_and_drops_who_is_in_no_group():
    grid, label = grouped(_grid(), [["p3", "p4"], ["p2", "p1"]])
    assert grid.partners == ("p1", "p2", "p3", "p4") and label.tolist() == [1, 1, 0, 0]
    assert competence(grid) == {"p1": 6.0, "p2": 5.0, "p3": 7.0, "p4": 6.0}


def test_the_merged_groups_relabel_the_grouped_members_as_the_library_names_them(tmp_path):
    from services.growth.library import MERGED, merged_label

    ws = _workspace(tmp_path, 1.0)
    ws.out.mkdir()
    label = np.array([0, 1, 2, 3, 2])
    assert merged_label(ws, "shooter", label).tolist() == label.tolist()  # nothing merged
    (ws.out / MERGED).write_text(json.dumps({"shooter": {"groups": [["G1", "G3"], ["G2"], ["G4"]]}}))
    assert merged_label(ws, "shooter", label).tolist() == [0, 1, 0, 2, 0]
