"""The command line as a whole: every command in a panel of `tsf --help`, and `tsf --version`."""

from __future__ import annotations

import re
import subprocess
import sys

from services.commands.app import PANEL, PANELS, app, name_of
from shared import provenance


def test_every_command_and_group_sits_in_one_panel_of_the_help_in_the_panels_order():
    names = [name_of(c) for c in app.registered_commands] + [g.name for g in app.registered_groups]
    assert sorted(names) == sorted(PANEL)  # a new command needs a panel; a panel names no stale one
    shown = [name_of(c) for c in app.registered_commands]
    panels = list(dict.fromkeys(PANEL[n] for n in shown))
    assert panels == [p for p in PANELS if any(PANEL[n] == p for n in shown)]
    assert shown[:3] == ["match", "play", "replay"]  # the everyday commands first


def test_the_help_shows_the_panels_in_order():
    run = subprocess.run(
        [sys.executable, "-m", "services.commands", "--help"], capture_output=True, text=True, timeout=120,
        env={"COLUMNS": "100", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(provenance.ROOT)},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    titles = re.findall(r"╭─ ([A-Za-z -]+?) ─", run.stdout)
    assert titles == ["Options", *PANELS]


def test_the_version_names_the_version_the_commit_and_the_contract():
    run = subprocess.run(
        [sys.executable, "-m", "services.commands", "--version"], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    commit = provenance.commit()
    version = provenance.project_version()
    expected = rf"tsf {re.escape(version)}(, commit {commit[:12]}(\+dirty)?)? \(wire contract schema \d+\)"
    assert re.fullmatch(expected, run.stdout.strip())
    assert (commit == "unknown") == (", commit" not in run.stdout)
