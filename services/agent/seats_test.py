"""What `tsf keys` lists is what loads: every key, by library, plays its seat."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.agent import library
from services.agent.seats import libraries, listed_keys, policy_for


def test_every_listed_key_loads_and_plays_its_seat() -> None:
    rows = listed_keys()
    names = {"study", "grown", "tuned", "population", "population-3", "rules"}
    assert {name for _, _, name, _ in rows} == names
    for key, seat, _, _ in rows:
        assert policy_for(key, seat).role == seat, key


def test_the_libraries_are_named_by_what_they_are(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    keys = {
        n: [key for key, _, name, _ in listed_keys("bait") if n == name] for n in ("study", "grown", "tuned")
    }
    assert keys["study"] == [f"B{i}" for i in range(1, 10)] and keys["grown"][0] == "GB1"
    assert keys["tuned"][0] == "TB1"
    monkeypatch.setenv("TSF_LIBRARY", str(library.NAMED["grown"]))  # a shipped one keeps its name
    assert list(libraries()) == ["study", "grown", "tuned", "population", "population-3"]
    (tmp_path / "mine").mkdir()
    monkeypatch.setenv("TSF_LIBRARY", str(tmp_path / "mine"))
    assert list(libraries())[-1] == f"yours ({tmp_path / 'mine'})"
