"""Figures of the adapter evaluation: identification accuracy against the window, each adaptive
agent's difference from the best static policy (bars with standard errors, the default marked), and the
log-probability curves of each library policy over one game (as in the study's figure)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - after choosing the file-only backend
import numpy as np  # noqa: E402

from services.evaluation.results import Comparison, percent, percent_text  # noqa: E402
from services.population.adaptive import ADAPTIVE, SHIPPED  # noqa: E402
from shared.game import FPS  # noqa: E402
from shared.plots import save  # noqa: E402

GOALS = {150: 0.80, 400: 0.95, 800: 0.99}


def accuracy_vs_window(identification: dict, path: Path) -> Path:
    by_window = {int(w): values for w, values in identification["windows"].items()}  # JSON keys are text
    windows = sorted(by_window)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for label, field in (("CEM window (argmax)", "accuracy"), ("Bayesian filter", "bayes_accuracy")):
        ax.plot(windows, [by_window[w][field] for w in windows], "o-", label=label)
    goals = [w for w in windows if w in GOALS]
    ax.plot(goals, [GOALS[w] for w in goals], "k_", markersize=18, mew=2, label="goal")
    ax.set(xlabel="window T (frames)", ylabel="identification accuracy", ylim=(0, 1.02))
    ax.set_title("Library partners with 10 % action noise", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def adaptive_vs_static(comparison: Comparison, path: Path, default: str = SHIPPED.name) -> Path:
    """The headline figure: each adaptive agent's paired difference from the best static policy in
    kills/min (mean ± s.e. over the same partners and seeds), as horizontal bars from zero, with the
    difference in per cent of the best static mean; the shipped default agent is marked. A difference is
    drawn, not the two means, because a gain of a few per cent is invisible on an axis from zero."""
    best, base, tests = comparison.best_static, comparison.base, comparison.tests
    names = list(tests)
    diffs = np.array([tests[a]["mean_difference"] for a in names])
    errors = np.array([tests[a]["stderr"] for a in names])
    labels = [a.removeprefix(ADAPTIVE) + (" (default)" if a == default else "") for a in names]
    width = 5.5 + 0.065 * max(map(len, labels))  # room for the longest label beside the bars
    fig, ax = plt.subplots(figsize=(width, 1.4 + 0.42 * len(names)))
    colours = ["tab:green" if a == default else "tab:orange" for a in names]
    rows = np.arange(len(names))
    ax.barh(rows, diffs, xerr=errors, color=colours, capsize=3)
    ax.axvline(0, color="black", linewidth=1)
    ax.set_yticks(rows, labels, fontsize=8)
    for tick, name in zip(ax.get_yticklabels(), names, strict=True):
        tick.set_fontweight("bold" if name == default else "normal")
    ax.invert_yaxis()
    reach = float(max(np.max(diffs + errors), 0.0))
    low = float(min(np.min(diffs - errors), 0.0))
    for row, d, e in zip(rows, diffs, errors, strict=True):
        text = f"{d:+.3f} ± {e:.3f} ({percent_text(percent(d, base))})"
        ax.text(max(d + e, 0.0) + 0.02 * (reach - low), row, text, va="center", fontsize=7)
    ax.set_xlim(low - 0.05 * (reach - low), reach + 0.75 * (reach - low))
    ax.set_xlabel(f"kills/min minus the best static policy, {best} ({base:.2f}): paired mean ± s.e.")
    ax.set_title(
        f"Adaptive agents against {best}: {comparison.partners} partners, "
        f"{comparison.units} paired games each",
        fontsize=10,
    )
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


def redraw(directory: Path) -> list[Path]:
    """Draw an evaluation's figures again from its shipped numbers (`identification.json`,
    `comparison.json` in `directory`, as `tsf eval` wrote them), after a change of the figures."""
    drawn = []
    if (ident := directory / "identification.json").exists():
        drawn.append(accuracy_vs_window(json.loads(ident.read_text()), directory / "identification.png"))
    if (comparison := directory / "comparison.json").exists():
        drawn.append(
            adaptive_vs_static(
                Comparison.of(json.loads(comparison.read_text())), directory / "adaptive_vs_static.png"
            )
        )
    return drawn


def _save(fig: plt.Figure, path: Path) -> Path:
    return save(fig, path, 120)
