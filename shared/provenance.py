"""What made an artifact: one record that every report, evaluation summary, table, recording and
library entry carries, so that a number can be traced to the code, the policies and the rules
behind it.

    date      when (UTC, ISO 8601)
    version   the project's version (its installed metadata), or "unknown"
    commit    the git commit of the checkout the code runs from ("+dirty" with local changes), or "unknown"
    library   the policy libraries' manifest hash (services/agent/library.py: provenance_hashes)
    table     the self-play table's file hash, or "none"

The caller hands it the library's and the table's hashes: this module stands below the packages
that know what a library or a table is.
    config    the game rules' hash (GameConfig.hash)
    command   the command line
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import shlex
import subprocess
import sys
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from shared.game import GameConfig

ROOT = Path(__file__).resolve().parent.parent
FIELDS = ("date", "version", "commit", "library", "table", "config", "command")
_command: list[str] = []  # the `tsf` command line being run (services/commands/entry.py), else sys.argv
COMMAND = "TSF_COMMAND"  # "<pid> <command line>" of the `tsf` command that started this process tree


def set_command(args: list[str]) -> None:
    """Name the `tsf` command line being run (its arguments), for the records made while it runs. A
    process that a `tsf` command started (the recorder of `tsf match`) names that command instead:
    it is what the user typed."""
    pid, _, line = os.environ.get(COMMAND, "").partition(" ")
    if line and pid != str(os.getpid()):
        _command[:] = shlex.split(line)
        return
    _command[:] = ["tsf", *args]
    os.environ[COMMAND] = f"{os.getpid()} {shlex.join(_command)}"


@cache
def project_version() -> str:
    try:
        return version("team-space-fortress")
    except PackageNotFoundError:
        return "unknown"


@cache
def commit() -> str:
    """The checkout's commit, "+dirty" when files differ from it; "unknown" outside a git checkout
    (also for a copy installed into a virtual environment that lies inside some checkout)."""
    try:
        head = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--show-toplevel", "HEAD"],
            capture_output=True, text=True, timeout=10,
        )  # fmt: skip
        top, _, sha = head.stdout.strip().partition("\n")
        if head.returncode != 0 or Path(top).resolve() != ROOT:  # an installed copy inside some checkout
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=10,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return sha + ("+dirty" if dirty.stdout.strip() else "")


def file_hash(path: Path | None) -> str:
    """A file's short sha256, "none" without one."""
    if path is None or not Path(path).exists():
        return "none"
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def provenance(
    library: str, table: str, config: GameConfig | None = None, command: list[str] | None = None
) -> dict[str, str]:
    """The record of FIELDS for an artifact made now with this library and table (their hashes, or
    names such as "self") and these rules."""
    argv = command or _command or sys.argv
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "version": project_version(),
        "commit": commit(),
        "library": library,
        "table": table,
        "config": (config or GameConfig()).hash(),
        "command": shlex.join(["tsf", *argv[1:]] if Path(argv[0]).name == "tsf" else argv),
    }


def lines(record: dict[str, str]) -> list[str]:
    """The record as `field: value` lines, in FIELDS order."""
    return [f"{name}: {record.get(name, 'unknown')}" for name in FIELDS]


def sidecar(recording: Path) -> Path:
    """Where the recorder names what made a recording: `<match>.provenance.json` beside it."""
    return recording.with_name(recording.name.removesuffix(".tsflog") + ".provenance.json")


def read_sidecar(recording: Path) -> dict[str, str] | None:
    """The provenance beside a recording, or None (none written, or unreadable)."""
    try:
        record = json.loads(sidecar(recording).read_text())
    except (OSError, ValueError):
        return None
    return {name: str(record.get(name, "unknown")) for name in FIELDS} if isinstance(record, dict) else None
