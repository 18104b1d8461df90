"""Files written whole or not at all: a reader (or a run resumed after a kill) finds either the
old file or the new one, never half of one. A stage's record, a library's manifest."""

from __future__ import annotations

import json
from pathlib import Path


def write_json(path: Path, record: object) -> None:
    """`record` as indented JSON at `path` (its directory made if need be), by way of PATH.partial:
    a file that exists is complete, so its existence can mark work as done."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(record, indent=1) + "\n")
    partial.replace(path)
