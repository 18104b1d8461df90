import json
import re
import subprocess

from services.agent import library
from services.table.table import DEFAULT_TABLE, Table
from shared import provenance
from shared.game import GameConfig


def test_the_record_names_version_commit_hashes_and_the_command_line():
    provenance.set_command(["report", "a.tsflog", "--out", "r"])
    record = provenance.provenance(**library.provenance_hashes(), config=GameConfig(frames=60))
    assert tuple(record) == provenance.FIELDS
    head = subprocess.run(
        ["git", "-C", str(provenance.ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
    )
    assert record["commit"].removesuffix("+dirty") == head.stdout.strip()
    version = re.search(r'^version = "(.+)"$', (provenance.ROOT / "pyproject.toml").read_text(), re.M)[1]
    assert record["version"] == version and record["library"] == library.manifest_hash()
    assert record["table"] == provenance.file_hash(DEFAULT_TABLE) != "none"
    assert record["config"] == GameConfig(frames=60).hash() != GameConfig().hash()
    assert record["command"] == "tsf report a.tsflog --out r"
    assert provenance.lines(record)[1] == f"version: {version}"


def test_outside_a_git_checkout_the_commit_is_unknown(tmp_path, monkeypatch):
    monkeypatch.setattr(provenance, "ROOT", tmp_path)
    provenance.commit.cache_clear()
    try:
        assert provenance.commit() == "unknown"
    finally:
        provenance.commit.cache_clear()


def test_a_saved_table_names_what_made_it(tmp_path):
    path = tmp_path / "table.json"
    Table.load(DEFAULT_TABLE).save(path)
    made = json.loads(path.read_text())["provenance"]
    assert made["library"] == library.manifest_hash() and made["table"] == "self"
    assert Table.load(path).library == made["library"]  # the table still loads


def test_an_eval_summary_names_what_made_it(tmp_path):
    from services.evaluation.results import write_results

    summary = write_results(tmp_path, None, [], None).read_text()
    made = json.loads((tmp_path / "provenance.json").read_text())
    assert tuple(made) == (*provenance.FIELDS, "population")  # an evaluation names its population too
    assert "## Provenance" in summary and f"- commit: {made['commit']}" in summary


def test_a_process_started_by_a_tsf_command_names_that_command(monkeypatch):
    monkeypatch.setenv(provenance.COMMAND, "1 tsf match --duration 2")  # another process's
    provenance.set_command(["recorder", "--match", "m"])
    assert provenance.provenance("l", "t")["command"] == "tsf match --duration 2"
    monkeypatch.delenv(provenance.COMMAND)
    provenance.set_command(["recorder", "--match", "m"])
    assert provenance.provenance("l", "t")["command"] == "tsf recorder --match m"
