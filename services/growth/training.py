"""Training as jobs of the job system (kind `train`, the `train` extra): one recipe of a library
directory trained to each of its levels in turn, each level kept as a policy of its own.

`tsf train`'s machinery does the work (train.train): every level resumes the same run from its
checkpoint (a run killed part way resumes too), the library gets the curve's best point so far, and
the level's weights and manifest entry are copied under the level's key (`PB03` at its levels:
`PB03a`, `PB03b`, ...). A best response has one level, its own key."""

from __future__ import annotations

from pathlib import Path

from services.agent import library
from services.training.loop import train


def run_train_jobs(args: list[dict]) -> list[list]:
    """Each job's last level's kills/min with its curve partner (on seeds no selection plays)."""
    return [
        [train_levels(a["key"], Path(a["library"]), a["levels"], Path(a["runs"]), a.get("warm_start", False))]
        for a in args
    ]


def train_levels(key: str, root: Path, levels: dict[str, int], runs: Path, warm_start: bool = False) -> float:
    entry: dict = {}
    for name, steps in levels.items():
        every = max(steps // 4, 50_000)
        entry = train(
            key, root, steps=steps, run_dir=runs, progress=False, every=every, warm_start=warm_start
        )
        if name != key:
            library.record_entry(root, name, library.copy_member(root, entry, root, name))
    return float(entry.get("score", {}).get("kills_per_minute", 0.0))
