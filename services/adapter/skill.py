"""The adapter's skill estimate: how practised is the partner, from the same window of frames.

The skill table (services/evaluation/skills.py) measures what works with the stand-ins of each style
and skill; P measures what works with library policies. Which row to read needs the partner's
skill as well as its style. From the last T frames of the partner's keys the window shows
(keys.py, the readings the stand-ins' fit uses too):

- `hold_ms`: the commonest run of the turn and thrust keys. A person's shortest press is the
  floor of their runs: 3 frames for a novice, 2 for a typical or practised hand, 1 for a policy.
- `key_changes_per_s`: a person who looks less often changes keys less often.
- `still_share`: the share of frames alive in runs of 0.5 s or more without a key change (lapses).
- `best_score`: the window's best mean log-probability under the library (the style estimate's
  own number): slips, delay and lapses make a hand's keys less like any policy's.

Each level (novice, typical, practised, or a library policy) is a Gaussian over these, per style,
fitted on windows of stand-ins' games (`tsf skill-model`); the posterior over levels mixes the
styles by the style estimate's belief. Typical and practised hands share their shortest press, so
the window tells them apart only by small differences: the choice reads the skill table under the
posterior, not one level. A window far from every level it knows (PLAUSIBLE) is no estimate.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.agent import library
from services.population.keys import LAPSE, changes, shortest_runs, still
from shared.game import FPS, split_action
from shared.provenance import provenance

LEVELS = ("novice", "typical", "practised", "library")  # the skill table's skills, then P's partners
PEOPLE = len(LEVELS) - 1
FEATURES = ("hold_ms", "key_changes_per_s", "still_share", "best_score")
SPREAD = np.array([5.0, 0.5, 0.01, 0.05])  # the least standard deviation of each feature (ours)
EVERY = 30  # frames between estimates (1 s): reading the keys costs more than a frame's update
CONFIDENT = 0.9  # the posterior of a person (any skill) above which the skill table chooses
PLAUSIBLE = 4.0  # standard deviations: how far a window may be from its likeliest level in any feature
VERSION = 1


def window_features(actions: np.ndarray, alive: np.ndarray, best: float) -> np.ndarray:
    """FEATURES of one window: its actions and whether the partner was alive, frame by frame, and
    its best mean score under the library."""
    keys = np.array(split_action(actions))
    lapsed = (still(changes(keys), len(actions)) >= LAPSE) & alive
    return np.array(
        [
            shortest_runs([actions])["hold_ms"],
            len(changes(keys)) / len(actions) * FPS,
            lapsed.sum() / max(alive.sum(), 1),
            best,
        ]
    )


class Keys:
    """The last `size` actions of the partner and whether it was alive, in n lanes that see every
    frame together."""

    def __init__(self, lanes: int, size: int) -> None:
        self.actions = np.zeros((lanes, size), np.int64)
        self.alive = np.zeros((lanes, size), bool)
        self.filled = self.next = 0

    def push(self, actions: np.ndarray, alive: np.ndarray) -> None:
        self.actions[:, self.next], self.alive[:, self.next] = actions, alive
        size = self.actions.shape[1]
        self.next, self.filled = (self.next + 1) % size, min(self.filled + 1, size)

    def features(self, best: np.ndarray) -> np.ndarray:
        """(n, FEATURES) of each lane's window, oldest frame first; `best`: (n,) best mean scores."""
        order = (np.arange(self.filled) + self.next - self.filled) % self.actions.shape[1]
        return np.array(
            [
                window_features(a[order], alive[order], b)
                for a, alive, b in zip(self.actions, self.alive, best, strict=True)
            ]
        )


@dataclass(frozen=True)
class SkillModel:
    """The skill table's means, and each level's features per style, for our seat `role`."""

    role: str
    styles: tuple[str, ...]  # the partner's library, in the payoff's order
    teammates: tuple[str, ...]  # ours, in the payoff's order
    window: int  # the T its features were measured at
    values: np.ndarray  # (styles, PEOPLE, teammates) kills/min of the skill table
    mean: np.ndarray  # (styles, LEVELS, FEATURES)
    sd: np.ndarray  # (styles, LEVELS, FEATURES)
    seeds: tuple[int, ...]  # the games its features were measured on
    library: str

    def posterior(self, features: np.ndarray, belief: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, LEVELS) posterior of each lane's level from its (n, FEATURES) window and (n, styles)
        belief about the style, from a uniform prior; and (n,) whether the window is within
        PLAUSIBLE deviations in every feature of its likeliest (style, level). A posterior only
        ranks the levels it knows: a scripted partner or a wrapped policy that changes keys
        frame by frame but rarely, like nothing measured, would otherwise be sure of some level."""
        sd = np.maximum(self.sd, SPREAD)
        z = (features[:, None, None, :] - self.mean[None]) / sd[None]
        log_like = (-0.5 * z**2 - np.log(sd)[None]).sum(axis=-1)  # (n, styles, LEVELS)
        top = log_like.max(axis=(1, 2), keepdims=True)
        joint = belief[:, :, None] * np.exp(log_like - top)
        likeliest = joint.reshape(len(joint), -1).argmax(axis=1)
        far = np.abs(z).max(axis=-1).reshape(len(z), -1)[np.arange(len(z)), likeliest]
        mixed = joint.sum(axis=1)
        return mixed / np.maximum(mixed.sum(axis=1, keepdims=True), 1e-300), far <= PLAUSIBLE

    def expected(self, belief: np.ndarray, posterior: np.ndarray) -> np.ndarray:
        """(n, teammates) the skill table's expected kills/min under the style belief and the
        posterior over the people's levels."""
        people = posterior[:, :PEOPLE] / np.maximum(posterior[:, :PEOPLE].sum(axis=1, keepdims=True), 1e-300)
        return np.einsum("ns,nl,sld->nd", belief, people, self.values)

    def save(self, path: Path, command: str = "") -> Path:
        record = {
            "version": VERSION,
            "library": self.library,
            "role": self.role,
            "styles": list(self.styles),
            "teammates": list(self.teammates),
            "levels": list(LEVELS),
            "features": list(FEATURES),
            "window": self.window,
            "seeds": list(self.seeds),
            "values": np.round(self.values, 6).tolist(),
            "mean": np.round(self.mean, 6).tolist(),
            "sd": np.round(self.sd, 6).tolist(),
            "provenance": provenance(self.library, "self") | {"command": command},
        }
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1) + "\n")
        return path

    @classmethod
    def load(cls, path: Path) -> SkillModel:
        record = json.loads(Path(path).read_text())
        if record.get("version") != VERSION or tuple(record.get("levels", ())) != LEVELS:
            raise ValueError(f"{path}: skill model format {record.get('version')}, expected {VERSION}")
        arrays = {k: np.array(record[k], np.float64) for k in ("values", "mean", "sd")}
        names = {k: tuple(record[k]) for k in ("styles", "teammates", "seeds")}
        return cls(record["role"], window=int(record["window"]), library=record["library"], **names, **arrays)


def skill_path() -> Path:
    """Where the adapter's skill model is: beside the table and the thresholds, bound like them."""
    return library.roots()[-1] / "skill.json"
