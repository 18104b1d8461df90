"""The held-out oracle, written once: what a teammate that knows its partner in advance scores by
choosing one column (a static policy, a library member) per partner, without the luck of choosing
on the games it is scored on. Each partner's seeds alternate between two halves (even and odd
positions, in seed order); each half is scored by the column best on the other half. A partner with
a single game is chosen on it.

The evaluation's known-partner headroom (team.py) and the growth's coverage headroom
(services/growth/choice.py, a layer above) both read it from here.
"""

from __future__ import annotations

import numpy as np

HALVES = (slice(0, None, 2), slice(1, None, 2))  # a partner's seeds, in order: even, odd positions


def chosen_on_other_half(kills: np.ndarray) -> np.ndarray:
    """(P, S): each partner's game (rows of `kills`, (P, C, S)) scored with the column whose mean
    on the partner's other half of seeds is best (the first such column on a tie)."""
    partners, _, seeds = kills.shape
    scored = np.empty((partners, seeds))
    rows = np.arange(partners)
    for own, other in (HALVES, HALVES[::-1]):
        if not len(range(seeds)[own]):
            continue
        chooser = kills[:, :, other] if seeds > 1 else kills[:, :, own]
        choice = chooser.mean(axis=2).argmax(axis=1)
        scored[:, own] = kills[rows, choice][:, own]
    return scored


def oracle(kills: np.ndarray) -> float:
    """The oracle's mean kills/min over every partner and seed of `kills` (P, C, S)."""
    scored = chosen_on_other_half(kills)
    halves = (np.ascontiguousarray(scored[:, half]).sum() for half in HALVES)  # half by half, as summed
    return float(sum(halves) / scored.size)
