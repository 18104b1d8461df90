"""Figures of the adapter evaluation: identification accuracy against the window, the adaptive
agent against every static policy (bars with standard errors, as in the study), and the
log-probability curves of each library policy over one game (as in the study's figure)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - after choosing the file-only backend
import numpy as np  # noqa: E402

from services.adapter.core import ADAPTIVE  # noqa: E402
from shared.game import FPS  # noqa: E402

GOALS = {150: 0.80, 400: 0.95, 800: 0.99}


def accuracy_vs_window(identification: dict, path: Path) -> Path:
    windows = sorted(int(w) for w in identification["windows"])
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for label, field in (("CEM window (argmax)", "accuracy"), ("Bayesian filter", "bayes_accuracy")):
        ax.plot(windows, [identification["windows"][w][field] for w in windows], "o-", label=label)
    goals = [w for w in windows if w in GOALS]
    ax.plot(goals, [GOALS[w] for w in goals], "k_", markersize=18, mew=2, label="goal")
    ax.set(xlabel="window T (frames)", ylabel="identification accuracy", ylim=(0, 1.02))
    ax.set_title("Library partners with 10 % action noise", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def adaptive_vs_static(comparison: dict, path: Path) -> Path:
    agents = comparison["agents"]
    names = sorted(agents, key=lambda a: (a.startswith(ADAPTIVE), a))
    means = [agents[a]["mean"] for a in names]
    errors = [agents[a]["stderr"] for a in names]
    colors = ["tab:orange" if a.startswith(ADAPTIVE) else "tab:blue" for a in names]
    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(names)), 4))
    ax.bar(range(len(names)), means, yerr=errors, color=colors, capsize=3)
    best = comparison["best_static"]
    ax.axhline(agents[best]["mean"], color="grey", linestyle="--", linewidth=1, label=f"best static ({best})")
    ax.set_xticks(range(len(names)), [a.removeprefix(ADAPTIVE) for a in names], rotation=45, ha="right")
    ax.set_ylabel("team kills / min (mean ± s.e.)")
    ax.set_title(
        f"{comparison['partners']} partners × seeds = {comparison['units']} games per agent", fontsize=10
    )
    ax.legend(fontsize=8)
    return _save(fig, path)


def logprob_curves(
    scores: np.ndarray, keys: list[str], window: int, title: str, path: Path, mark: int = 0
) -> Path:
    """Each library policy's mean log-probability of the partner's actions over the last `window`
    frames, at every frame of one game; `mark` draws a line at a frame (e.g. a partner's switch)."""
    sums = np.cumsum(scores, axis=0)
    counts = np.minimum(np.arange(1, len(scores) + 1), window)[:, None]
    shifted = np.vstack([np.zeros((window, scores.shape[1])), sums[:-window]])[: len(scores)]
    means = (sums - shifted) / counts
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, key in enumerate(keys):
        ax.plot(np.arange(len(scores)) / FPS, means[:, i], label=key, linewidth=1.2)
    if mark:
        ax.axvline(mark / FPS, color="black", linestyle=":", linewidth=1)
    ax.set(xlabel="time (s)", ylabel=f"mean log-probability over the last {window} frames")
    ax.set_title(title, fontsize=10)
    ax.legend(ncol=3, fontsize=7)
    return _save(fig, path)


def _save(fig: plt.Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
