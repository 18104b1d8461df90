"""A person's pairs out of real recordings (written in-process as the recorder writes them): which
seats count, what is left out by name, the split by participant, and every refusal."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from services.proxy.data import extract, split
from services.proxy.synthetic import record_trial
from services.recorder.recording import load
from services.recorder.recording_test import Script, record_match
from services.sim import observation as ob
from shared.errors import Failure, UsageError
from shared.game import GameConfig

SHORT = GameConfig(frames=150)


def trials(
    directory: Path,
    people: int = 3,
    role: str = "bait",
    person: str = "human(B5)",
    config: GameConfig = SHORT,
) -> list[Path]:
    """One short trial per stand-in participant p0, p1, ..."""
    agent = "S5" if role == "bait" else "B5"
    return [
        record_trial(directory / f"t-p{p}.tsflog", person, role, agent, 100 + 3 * p, f"p{p}", config)
        for p in range(people)
    ]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> list[Path]:
    return trials(tmp_path_factory.mktemp("proxy-data"))


def test_pairs_are_the_persons_observations_and_the_applied_actions(recorded):
    data = extract(recorded, "bait")
    assert data.participants == ["p0", "p1", "p2"]
    assert [s.participant for s in data.sources] == ["p0", "p1", "p2"]
    recording = load(recorded[0])
    states = {s.frame: s for s in recording.states}
    alive = [f for f in range(SHORT.frames) if states[f].obs["bait"][ob.SELF + ob.ALIVE] >= 0.5]
    first = data.rows(["p0"])
    assert len(first) == len(alive) == data.sources[0].frames
    np.testing.assert_array_equal(data.actions[first], [states[f + 1].applied[0] for f in alive])
    np.testing.assert_array_equal(data.obs[first], np.float32([states[f].obs["bait"] for f in alive]))
    before = [[states[f - k].applied[0] if f - k > 0 else 0 for k in range(4)] for f in alive]
    np.testing.assert_array_equal(data.previous[first], before)
    assert data.previous[first][0].tolist() == [0, 0, 0, 0] and alive[0] == 0
    assert all("shooter seat, agent S5" in line for line in data.excluded) and len(data.excluded) == 3


def test_the_split_is_by_participant_and_reproducible(recorded):
    data = extract(recorded, "bait")
    parts = split(data, 0.34, seed=3, min_frames=10)
    assert set(parts.train) | set(parts.held_out) == set(data.participants)
    assert not set(parts.train) & set(parts.held_out) and len(parts.held_out) == 1
    assert split(data, 0.34, seed=3, min_frames=10) == parts
    held = set(data.people[data.rows(parts.held_out)])
    assert held == {data.participants.index(parts.held_out[0])}


def test_a_dropped_attempt_is_left_out_by_name(recorded, tmp_path):
    dropped = record_trial(tmp_path / "d.tsflog", "human(B5)", "bait", "S5", 7, "p9", SHORT, status="dropped")
    data = extract([*recorded, dropped], "bait")
    assert "p9" not in data.participants
    assert any(line.startswith(str(dropped)) and "dropped" in line for line in data.excluded)


def test_without_a_sidecar_the_start_records_human_seat_counts(tmp_path):
    path = trials(tmp_path, 1)[0]
    path.with_name("t-p0.study.json").unlink()
    data = extract([path], "bait")
    assert data.participants == ["t-p0"] and len(data.actions) > 0


def test_a_recording_without_a_person_is_refused(recorded, tmp_path):
    agents = tmp_path / "agents.tsflog"
    record_match(agents, script=Script(match="agents", frames=40, statuses=(), switches=()))
    with pytest.raises(UsageError, match="no person's seat"):
        extract([*recorded, agents], "bait")


def test_mixed_roles_are_refused(recorded, tmp_path):
    shooter = trials(tmp_path, 1, role="shooter", person="human(S5)")
    with pytest.raises(UsageError, match="one seat at a time"):
        extract([*recorded, *shooter], "bait")


def test_a_damaged_recording_is_refused(recorded, tmp_path):
    damaged = tmp_path / "damaged.tsflog"
    data = bytearray(recorded[0].read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)
    damaged.write_bytes(bytes(data))
    with pytest.raises(Failure, match="damaged recording"):
        extract([recorded[1], damaged], "bait")


def test_too_little_data_is_refused(recorded):
    data = extract(recorded[:1], "bait")
    with pytest.raises(Failure, match="1 participant"):
        split(data)
    with pytest.raises(Failure, match="too little data"):
        split(extract(recorded, "bait"), min_frames=10_000)


def test_a_sidecars_role_names_the_persons_seat(recorded, tmp_path):
    path = trials(tmp_path, 1)[0]
    sidecar = path.with_name("t-p0.study.json")
    sidecar.write_text(json.dumps({**json.loads(sidecar.read_text()), "role": "shooter"}))
    with pytest.raises(UsageError, match="played the shooter seat"):
        extract([path], "bait")
