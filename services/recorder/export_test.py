"""Recordings as tidy data: `tsf export` writes one typed Parquet file per table and match, and
the files of several matches read as one table in DuckDB and in pandas."""

from __future__ import annotations

from pathlib import Path

import duckdb
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from services.commands.app import app
from services.commands.entry import run
from services.recorder.export import SCHEMAS, TABLES, TIME
from services.recorder.recording import load
from services.recorder.recording_test import Script, record_match

MATCHES = ("study-a", "study-b")


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    logs = tmp_path_factory.mktemp("logs")
    paths = []
    for i, match in enumerate(MATCHES):
        paths.append(logs / f"{match}.tsflog")
        record_match(paths[-1], script=Script(match=match, seed=i, frames=400, statuses=(), switches=()))
    out = tmp_path_factory.mktemp("tables")
    assert run(app, ["export", *map(str, paths), "--out", str(out)]) == 0
    return out, paths


def test_one_file_per_table_and_match_every_one_with_a_match_column_and_its_types(exported):
    out, paths = exported
    assert sorted(p.name for p in out.iterdir()) == sorted(
        f"{m}.{t}.parquet" for m in MATCHES for t in TABLES
    )
    for match in MATCHES:
        for table in TABLES:
            read = pq.read_table(out / f"{match}.{table}.parquet")
            assert read.schema.equals(SCHEMAS[table], check_metadata=False), table
            assert set(read["match"].to_pylist()) <= {match}
    states = pq.read_table(out / "study-a.states.parquet")
    assert states.schema.field("sent").type == TIME and pa.types.is_struct(
        states.schema.field("fortress").type
    )
    assert pa.types.is_struct(states.schema.field("bait_ship").type)
    match = pq.read_table(out / "study-a.match.parquet").to_pylist()[0]
    assert match["policies"] == {"bait": "circle", "shooter": "mirror"} and match["config"]["frames"] == 400
    assert sum(c["kills"] for c in dict(match["counters"]).values()) == match["kills"] > 0
    assert match["exported_by"]["command"].startswith("tsf export") and match["exported_by"]["config"]


def test_missiles_and_shells_are_tables_of_their_own(exported):
    out, paths = exported
    recording = load(paths[0])
    missiles = pd.read_parquet(out / "study-a.missiles.parquet")
    shells = pd.read_parquet(out / "study-a.shells.parquet")
    assert len(missiles) == sum(len(s.missiles) for s in recording.states) > 0
    assert len(shells) == sum(len(s.shells) for s in recording.states) > 0
    assert set(missiles["owner"]) <= {"bait", "shooter"}


def test_an_empty_table_keeps_its_types(exported):
    out, _ = exported
    gaps = pd.read_parquet(out / "study-a.gaps.parquet")
    assert gaps.empty and list(gaps.columns) == ["match", "first", "last"]
    assert str(gaps["first"].dtype) == "int64"
    adapter = pq.read_table(out / "study-a.adapter.parquet")
    assert adapter.num_rows == 0 and pa.types.is_map(adapter.schema.field("scores").type)


def test_duckdb_and_pandas_read_the_matches_as_one_table(exported):
    out, _ = exported
    query = f"""
        SELECT s.match, count(*) AS frames, max(s.kills) AS kills, any_value(m.policies.bait) AS bait
        FROM '{out}/*.states.parquet' s JOIN '{out}/*.match.parquet' m USING (match)
        GROUP BY s.match ORDER BY s.match
    """  # the query docs/recording.md shows
    by_duckdb = duckdb.sql(query).df()
    states = pd.concat(pd.read_parquet(p) for p in sorted(out.glob("*.states.parquet")))
    matches = pd.concat(pd.read_parquet(p) for p in sorted(out.glob("*.match.parquet")))
    matches["bait"] = matches["policies"].map(lambda p: p["bait"])
    by_pandas = (
        states.groupby("match").agg(frames=("frame", "size"), kills=("kills", "max")).reset_index()
        .merge(matches[["match", "bait"]], on="match")
    )  # fmt: skip
    assert list(by_duckdb["match"]) == list(MATCHES) == list(by_pandas["match"])
    assert list(by_duckdb["frames"]) == list(by_pandas["frames"]) == [401, 401]
    assert list(by_duckdb["kills"]) == list(by_pandas["kills"])
    assert list(by_duckdb["bait"]) == ["circle", "circle"]


def test_export_refuses_a_damaged_recording_unless_asked_and_two_of_one_match(exported, tmp_path):
    _, paths = exported
    damaged = tmp_path / "cut.tsflog"
    damaged.write_bytes(paths[0].read_bytes()[:-40])
    assert run(app, ["export", str(damaged), "--out", str(tmp_path / "x")]) == 1
    assert run(app, ["export", str(damaged), "--out", str(tmp_path / "x"), "--allow-damaged"]) == 0
    assert (tmp_path / "x" / "study-a.states.parquet").exists()
    copy = tmp_path / "again.tsflog"
    copy.write_bytes(paths[0].read_bytes())
    assert run(app, ["export", str(paths[0]), str(copy), "--out", str(tmp_path / "y")]) == 2
