"""Calibration: the pairs the rules page names, each scored over seeded one-minute games."""

from __future__ import annotations

from services.agent.scripted import scripted_policy
from services.sim.play import Summary, play, summarize
from shared.game import GameConfig

# (label, bait seat's policy, shooter seat's policy)
PAIRS = (
    ("scripted pair", "circle", "mirror"),
    ("lone bait", "circle", "idle"),
    ("lone shooter", "idle", "mirror"),
    ("two baits (roles ignored)", "circle", "circle"),
    ("two shooters (roles ignored)", "mirror", "mirror"),
    ("random pair", "random", "random"),
)


def calibrate(games: int = 20, config: GameConfig | None = None) -> list[tuple[str, str, str, Summary]]:
    rows = []
    for label, bait, shooter in PAIRS:
        results = [
            play(scripted_policy(bait, "bait"), scripted_policy(shooter, "shooter"), seed, config)
            for seed in range(games)
        ]
        rows.append((label, bait, shooter, summarize(results)))
    return rows
