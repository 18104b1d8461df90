"""What a library leaves room for, and the library that leaves the most: pure functions over a
cross-play grid (partners x candidate teammates x seeds, kills/min).

- `headroom`: the held-out oracle headroom. Each partner's best library member is chosen on its
  other seeds (`oracle`, services/evaluation/oracle.py: its seeds alternate between two halves,
  each scored by the other's choice, as the evaluation's known-partner headroom is), and
  compared with the best single member (chosen on all the games, which favours it). What a
  teammate that knew its partner could gain by choosing: the most an adapter over that library
  can gain.
- `groups`: partners grouped by what works with them (k-means over their rows, each row scaled by
  its best value: the shape of what works, not how well), with the fewest groups whose regret (a
  member's best candidate against its group's best) is within the spec's bound.
- `select`: the greedy coverage selection (as HSP keeps its partners, and BRDiv looks for partners
  whose best responses differ): start from the best single candidate, add the candidate that
  raises the headroom most, until the next adds less than `gain` (relative) or the library is full.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.evaluation.oracle import oracle  # written once, for the evaluation too


@dataclass(frozen=True)
class Grid:
    """Kills/min of `partners` (rows) with `candidates` (columns) over seeds: (P, C, S)."""

    partners: tuple[str, ...]
    candidates: tuple[str, ...]
    kills: np.ndarray

    def columns(self, names: list[str]) -> np.ndarray:
        return self.kills[:, [self.candidates.index(n) for n in names]]

    def only(self, partners: list[str]) -> Grid:
        """The grid of `partners` alone (rows in that order)."""
        index = [self.partners.index(p) for p in partners]
        return Grid(tuple(partners), self.candidates, self.kills[index])

    def beside(self, more: Grid) -> Grid:
        """This grid with `more`'s columns after its own (the same partners, in the same order)."""
        if more.partners != self.partners:
            raise ValueError("grids of different partners side by side")
        return Grid(
            self.partners, self.candidates + more.candidates, np.concatenate([self.kills, more.kills], 1)
        )

    @classmethod
    def of(cls, record: dict) -> Grid:
        """A grid as a cross-play file holds it (`partners`, `candidates`, `kills` as lists)."""
        return cls(tuple(record["partners"]), tuple(record["candidates"]), np.array(record["kills"]))


def best_single(kills: np.ndarray) -> tuple[int, float]:
    """The column with the best mean over all partners and seeds, and that mean."""
    means = kills.mean(axis=(0, 2))
    return int(means.argmax()), float(means.max())


def headroom(kills: np.ndarray) -> float:
    """The held-out oracle headroom, relative to the best single column (0.25: +25 %)."""
    _, single = best_single(kills)
    return (oracle(kills) - single) / single if single > 0 else 0.0


def select(grid: Grid, most: int, gain: float) -> list[dict]:
    """The greedy selection's steps: each the library so far, its best single member's mean, its
    held-out oracle and headroom."""
    first, _ = best_single(grid.kills)
    chosen = [first]
    steps = [_step(grid, chosen)]
    while len(chosen) < min(most, len(grid.candidates)):
        rest = [c for c in range(len(grid.candidates)) if c not in chosen]
        scores = [headroom(grid.kills[:, [*chosen, c]]) for c in rest]
        best = int(np.argmax(scores))
        if scores[best] - steps[-1]["headroom"] < gain:
            break
        chosen.append(rest[best])
        steps.append(_step(grid, chosen))
    return steps


def _step(grid: Grid, chosen: list[int]) -> dict:
    kills = grid.kills[:, chosen]
    single, mean = best_single(kills)
    return {
        "library": [grid.candidates[c] for c in chosen],
        "best_single": grid.candidates[chosen[single]],
        "best_single_mean": round(mean, 4),
        "oracle": round(oracle(kills), 4),
        "headroom": round(headroom(kills), 4),
    }


def kmeans(rows: np.ndarray, k: int, seed: int, tries: int = 10, rounds: int = 100) -> np.ndarray:
    """Each row's cluster of k (Lloyd's algorithm, k-means++ starts, the best of `tries`)."""
    rng = np.random.default_rng(seed)
    best, best_cost = np.zeros(len(rows), np.int64), np.inf
    for _ in range(tries):
        centres = [rows[rng.integers(len(rows))]]
        for _ in range(1, k):
            d = np.min([((rows - c) ** 2).sum(axis=1) for c in centres], axis=0)
            centres.append(
                rows[rng.choice(len(rows), p=d / d.sum())] if d.sum() > 0 else rows[rng.integers(len(rows))]
            )
        centres = np.array(centres)
        for _ in range(rounds):
            label = ((rows[:, None, :] - centres[None]) ** 2).sum(axis=2).argmin(axis=1)
            moved = np.array(
                [rows[label == j].mean(axis=0) if (label == j).any() else centres[j] for j in range(k)]
            )
            if np.allclose(moved, centres):
                break
            centres = moved
        cost = ((rows - centres[label]) ** 2).sum()
        if cost < best_cost:
            best, best_cost = label, cost
    return best


def shape(means: np.ndarray) -> np.ndarray:
    """Each row (a partner's mean kills/min with each candidate) scaled by its best value: what works
    with the partner, whatever its level."""
    top = means.max(axis=1, keepdims=True)
    return means / np.where(top > 0, top, 1.0)


def regret(means: np.ndarray, label: np.ndarray) -> float:
    """How much the partners lose, relative to their own best candidate's mean, when each plays its
    group's best candidate."""
    own = means.max(axis=1)
    lost = 0.0
    for j in np.unique(label):
        rows = means[label == j]
        lost += (rows.max(axis=1) - rows[:, rows.mean(axis=0).argmax()]).sum()
    return float(lost / own.sum()) if own.sum() > 0 else 0.0


def groups(grid: Grid, most: int, bound: float, seed: int) -> tuple[np.ndarray, list[dict]]:
    """Each partner's group, from the fewest groups (1..most) whose regret is within `bound`, and
    the regret of each count tried."""
    means = grid.kills.mean(axis=2)
    rows, tried = shape(means), []
    for k in range(1, min(most, len(rows)) + 1):
        label = kmeans(rows, k, seed)
        tried.append({"groups": k, "regret": round(regret(means, label), 4)})
        if tried[-1]["regret"] <= bound:
            break
    return label, tried


def nearest(rows: np.ndarray, members: np.ndarray, label: np.ndarray) -> np.ndarray:
    """The group of each row: that of the nearest group centre (rows shaped as `shape` makes them)."""
    centres = np.array([members[label == j].mean(axis=0) for j in range(label.max() + 1)])
    return ((rows[:, None, :] - centres[None]) ** 2).sum(axis=2).argmin(axis=1)


def place(grid: Grid, train: Grid, label: np.ndarray) -> np.ndarray:
    """The group of each of `grid`'s (held-out) partners: the one whose training members' rows (what
    works with them, scaled by their best: `shape`) its own row is nearest."""
    rows = shape(grid.columns(list(train.candidates)).mean(axis=2))
    return nearest(rows, shape(train.kills.mean(axis=2)), label)


def partner_groups(
    grouping: Grid, label: np.ndarray, validation: Grid, members: list[str], teammates: list[str]
) -> list[dict]:
    """The adapter's view of one seat's partner groups: each group's members (the training members
    of `grouping`, labelled `label`, and the `members` among the validation partners, each in the
    group whose rows theirs is nearest) and the mean kills/min of the group's validation partners
    (members and stand-ins) with each of `teammates`: the data the library was selected on, which
    holds every candidate as a column."""
    placed = place(validation, grouping, label)
    values = validation.columns(teammates).mean(axis=2)
    out = []
    for j in range(label.max() + 1):
        rows = placed == j
        mine = [p for p, g in zip(grouping.partners, label, strict=True) if g == j]
        mine += [p for p, g in zip(validation.partners, placed, strict=True) if g == j and p in members]
        means = values[rows].mean(axis=0) if rows.any() else _training_means(grouping, label == j, teammates)
        out.append(
            {
                "name": f"G{j + 1}",
                "members": mine,
                "partners": int(rows.sum()),
                "values": [round(float(v), 4) for v in means],
            }
        )
    return out


def _training_means(grouping: Grid, rows: np.ndarray, teammates: list[str]) -> np.ndarray:
    """A group without validation partners: its training members' means (0 for a teammate that
    was no candidate then, a best response trained after the grouping)."""
    means = grouping.kills[rows].mean(axis=(0, 2))
    return np.array(
        [means[grouping.candidates.index(t)] if t in grouping.candidates else 0.0 for t in teammates]
    )


def identified(confusion: np.ndarray) -> float:
    """The share of frames the filter estimates the partner's own group: (true, estimated) counts."""
    total = confusion.sum()
    return float(np.trace(confusion) / total) if total > 0 else 0.0


def expected(confusion: np.ndarray, values: np.ndarray, weight: np.ndarray) -> float:
    """The mean kills/min an adapter gets that, on each estimate, plays the teammate best for the
    groups that estimate stands for (as Payoff.trust weighs them): each group weighted by `weight`
    (its partners), scored by how often it is estimated as each group."""
    seen = confusion.sum(axis=0, keepdims=True)
    trust = np.where(seen > 0, confusion / np.where(seen > 0, seen, 1), np.eye(len(confusion)))
    played = (trust.T @ values).argmax(axis=1)  # each estimate's teammate
    share = confusion / np.maximum(confusion.sum(axis=1, keepdims=True), 1)
    gets = (share * values[:, played]).sum(axis=1)
    return float(weight @ gets / weight.sum())


def merge(
    confusion: np.ndarray, values: np.ndarray, weight: np.ndarray, target: float, regret: float
) -> list[list[int]]:
    """Groups the calibrated filter cannot tell apart, merged: while the share identified is under
    `target`, the pair most often taken for each other is merged, unless that costs more than
    `regret` (relative) of what the adapter expects over the unmerged groups (`expected`). The
    partition, as lists of the original groups (each alone where nothing is merged)."""
    parts = [[j] for j in range(len(confusion))]
    start = expected(confusion, values, weight)
    while len(parts) > 1 and identified(confusion) < target:
        share = confusion / np.maximum(confusion.sum(axis=1, keepdims=True), 1)
        mixed = share + share.T
        np.fill_diagonal(mixed, -1.0)
        i, j = sorted(np.unravel_index(int(mixed.argmax()), mixed.shape))
        joined = _joined(confusion, values, weight, i, j)
        if expected(*joined) < start * (1 - regret):
            break
        confusion, values, weight = joined
        parts[i] += parts.pop(j)
    return parts


def _joined(
    confusion: np.ndarray, values: np.ndarray, weight: np.ndarray, i: int, j: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Groups i and j as one (i's place): their counts added, their rows averaged by weight."""
    keep = [k for k in range(len(confusion)) if k != j]
    confusion = confusion.copy()
    confusion[i] += confusion[j]
    confusion[:, i] += confusion[:, j]
    values = values.copy()
    values[i] = (weight[i] * values[i] + weight[j] * values[j]) / max(weight[i] + weight[j], 1e-12)
    weight = weight.copy()
    weight[i] += weight[j]
    return confusion[np.ix_(keep, keep)], values[keep], weight[keep]
