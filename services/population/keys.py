"""What a person's keys show, read off an action stream: when any key changes, each frame's run
without a change, the fire presses, the shortest holds. One reading for the stand-ins' fit
(humans.py) and the adapter's skill estimate (skill.py)."""

from __future__ import annotations

import numpy as np

from services.population.human_like import FRAME_MS, PARAMETERS
from shared.game import split_action

LAPSE = 15  # frames (0.5 s) alive without a key change: a lapse (or a long hold)


def changes(keys: np.ndarray) -> np.ndarray:
    """The frames at which any of the keys (3, frames) changes."""
    return np.flatnonzero((np.diff(keys, axis=1) != 0).any(axis=0)) + 1


def still(when: np.ndarray, frames: int) -> np.ndarray:
    """Each frame's run without a key change (frames), from the changes `when`."""
    lengths = np.diff(np.concatenate([[0], when, [frames]]))
    return np.repeat(lengths, lengths)


def fire_presses(keys: np.ndarray) -> np.ndarray:
    """The frames at which the fire key goes down (a press held from the first frame counts)."""
    return np.flatnonzero(np.diff(np.concatenate([[0], keys[2]])) == 1)


def shortest_runs(actions: list[np.ndarray]) -> dict[str, float]:
    """The holds, read directly, in ms over all games: the turn and thrust keys' commonest inner
    run (`hold_ms`: the model changes a dithering key as soon as its hold allows, so most runs are
    the hold, and a run the page's timing cuts a frame short, as in a study's recordings, does not
    move it); the fire key's shortest run down (`fire_ms`: a burst) and up (`fire_gap_ms`). A hold
    the keys never show is left to its longest bound."""
    found: dict[str, list[int]] = {"hold_ms": [], "fire_ms": [], "fire_gap_ms": []}
    for game in actions:
        for k, key in enumerate(split_action(game)):
            changes = np.flatnonzero(np.diff(key)) + 1
            runs, pressed = np.diff(changes), key[changes[:-1]] != 0
            if k < 2:
                found["hold_ms"] += runs.tolist()
            else:
                found["fire_ms"] += runs[pressed].tolist()
                found["fire_gap_ms"] += runs[~pressed].tolist()
    read = {"hold_ms": lambda runs: np.bincount(runs).argmax(), "fire_ms": min, "fire_gap_ms": min}
    return {
        name: float(read[name](runs) * FRAME_MS) if runs else PARAMETERS[name][1]
        for name, runs in found.items()
    }
