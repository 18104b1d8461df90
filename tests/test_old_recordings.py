"""Recordings that earlier versions of the project wrote, kept in tests/data/old-recordings (how each was
made: its README), read, replayed and exported by this version: one per schema version and per
change of a recorded message's fields. A field a type gained later reads as its documented
default (shared/messages.py, each type's ADDED); a recording that is truly damaged still says so."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import msgpack
import pytest

from services.commands.app import app
from services.commands.entry import run
from services.recorder.export import export, read
from services.recorder.log import LogWriter, read_log
from services.recorder.recording import load, replay
from shared.messages import RECORDED, SCHEMA_VERSION, Action, Summary

CORPUS = Path(__file__).parent / "data" / "old-recordings"
# name: (schema version, whether its actions and summary carry `failures`, whether an adapter played)
RECORDINGS = {
    "v1-2026-11-22": (1, False, False),  # the first recorded contract: no adapter status yet
    "v1-adapter-2026-12-01": (1, False, True),  # adapter statuses; actions and summaries without failures
    "v1-failures-2026-12-02": (1, True, True),  # policy failures counted in actions and the summary
    "v2-2026-12-02": (2, True, True),  # each family's id named for what it holds
}
FRAMES = 90  # each is a 3 s lockstep match of seed 3


def records(path: Path) -> list[dict]:
    return [msgpack.unpackb(record.data, raw=False) for record in read_log(path)[0] if record.gap is None]


def test_the_corpus_is_what_its_table_says() -> None:
    """Each file is what an earlier version wrote, of the version and fields its row says; the
    current schema version has a recording in it."""
    assert sorted(p.stem for p in CORPUS.glob("*.tsflog")) == sorted(RECORDINGS)
    assert max(version for version, _, _ in RECORDINGS.values()) == SCHEMA_VERSION
    for name, (version, failures, adapted) in RECORDINGS.items():
        written = records(CORPUS / f"{name}.tsflog")
        assert {r["v"] for r in written} == {version}, name
        actions = [r for r in written if r["type"] == "action"]
        summary = next(r for r in written if r["type"] == "summary")
        assert all(("failures" in r) == failures for r in [*actions, summary]), name
        assert any(r["type"] == "adapter" for r in written) == adapted, name


@pytest.mark.parametrize("name", RECORDINGS)
def test_an_old_recording_reads_replays_and_exports(name: str, tmp_path: Path) -> None:
    recording = load(CORPUS / f"{name}.tsflog")
    assert recording.problems() == [] and recording.undecodable == 0, recording.problems()
    assert len(recording.states) == FRAMES + 1 and recording.summary.frame == FRAMES
    # (earlier versions answered the last state too)
    assert len(recording.actions) in (2 * FRAMES, 2 * (FRAMES + 1))
    assert replay(recording) == []
    _, failures, adapted = RECORDINGS[name]
    if not failures:  # the fields added later read as their defaults
        assert {(a.failures, a.failure) for _, a in recording.actions} == {(0, "")}
        assert recording.summary.failures == {}
    assert bool(recording.adapter) == adapted
    export(recording, tmp_path / "tables")
    tables = {table: t.to_pydict() for table, t in read(tmp_path / "tables", recording.start.match).items()}
    assert len(tables["states"]["frame"]) == FRAMES + 1
    assert len(tables["actions"]["action"]) == len(recording.actions)
    assert tables["match"]["kills"] == [recording.summary.kills] and tables["match"]["clean"] == [True]


@pytest.mark.parametrize("name", RECORDINGS)
def test_tsf_replay_of_an_old_recording(name: str, capsys: pytest.CaptureFixture, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.setenv("COLUMNS", "400")
    assert run(app, ["replay", str(CORPUS / f"{name}.tsflog")]) == 0
    assert f"all {FRAMES + 1} states reproduce their hashes" in capsys.readouterr().out


def test_added_fields_are_optional_only_where_declared() -> None:
    """Only the fields a type gained after its first version may be missing from a record; they have
    defaults (what an old record reads as)."""
    assert {"failures", "failure"} == Action.ADDED and {"failures"} == Summary.ADDED
    for kind in RECORDED:
        fields = {f.name: f for f in dataclasses.fields(kind)}
        for name in kind.ADDED:
            field = fields[name]
            assert (field.default, field.default_factory) != (dataclasses.MISSING, dataclasses.MISSING)


def test_a_damaged_old_recording_still_says_so(tmp_path: Path) -> None:
    """An old record that lacks a field its version had is undecodable, and the reader says why."""
    path, actions = tmp_path / "damaged.tsflog", 0
    with LogWriter(path) as log:
        for record in read_log(CORPUS / "v1-2026-11-22.tsflog")[0]:
            data = msgpack.unpackb(record.data, raw=False)
            if data["type"] == "action":
                del data["policy"]  # a field every version's action has
                actions += 1
            log.write(record.key, msgpack.packb(data, use_bin_type=True), record.t)
    recording = load(path)
    assert recording.undecodable == actions and recording.actions == []
    assert f"{actions} undecodable records (first: shape: missing field 'policy')" in recording.problems()
    data = (CORPUS / "v1-2026-11-22.tsflog").read_bytes()
    cut = tmp_path / "cut.tsflog"
    cut.write_bytes(data[: len(data) // 2])
    assert any(p.startswith("torn tail") or p.startswith("no summary") for p in load(cut).problems())
