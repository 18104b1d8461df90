"""The table as a heatmap, laid out like the original study's: baits as rows, shooters as columns,
families separated by lines, each bait's best shooter outlined. The outlines are drawn above the
separators (BOXES over LINES), so that a box on a family's edge shows whole."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from services.agent import library  # noqa: E402
from services.table.table import Table  # noqa: E402
from shared.plots import save  # noqa: E402

LINES, BOXES = 2, 3  # the drawing order (zorder): the best responses' outlines over the separators


def family_breaks(keys: tuple[str, ...]) -> list[int]:
    """Indices where the registry family changes along `keys`."""
    families = [library.registry()[k].family for k in keys]
    return [i for i in range(1, len(keys)) if families[i] != families[i - 1]]


def heatmap(table: Table, path: Path) -> Path:
    means = [[table.mean(b, s) for s in table.shooters] for b in table.baits]
    fig, ax = plt.subplots(figsize=(1.0 + 0.9 * len(table.shooters), 1.0 + 0.6 * len(table.baits)))
    image = ax.imshow(means, cmap="viridis", aspect="auto")
    fig.colorbar(image, ax=ax, label="kills per minute")
    ax.set_xticks(range(len(table.shooters)), table.shooters)
    ax.set_yticks(range(len(table.baits)), table.baits)
    ax.set_xlabel("shooter")
    ax.set_ylabel("bait")
    top = max(max(row) for row in means) or 1.0
    for i, bait in enumerate(table.baits):
        best = table.shooters.index(table.best_shooter(bait))
        box = Rectangle((best - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2, zorder=BOXES)
        ax.add_patch(box)
        for j, value in enumerate(means[i]):
            ax.text(
                j, i, f"{value:.1f}", ha="center", va="center", color="white" if value < top / 2 else "black"
            )
    for j in family_breaks(table.shooters):
        ax.axvline(j - 0.5, color="white", linewidth=2, zorder=LINES)
    for i in family_breaks(table.baits):
        ax.axhline(i - 0.5, color="white", linewidth=2, zorder=LINES)
    ax.set_title(f"Self-play table P: mean kills/min over {table.games} games (red: best shooter)")
    return save(fig, path)


def skill_heatmap(table, path: Path, p_best: dict[str, str] | None = None) -> Path:  # noqa: ANN001 - a SkillTable
    """The skill table as a heatmap: stand-ins (style x skill) as rows, our seat's teammates as
    columns; each row's best teammate outlined red, and P's best response to the style (`p_best`:
    style -> teammate) dashed white, so that where they differ shows."""
    rows = table.partners
    means = [[table.mean(p, t) for t in table.teammates] for p in rows]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 + 0.8 * len(table.teammates)), 1.4 + 0.32 * len(rows)))
    image = ax.imshow(means, cmap="viridis", aspect="auto")
    fig.colorbar(image, ax=ax, label="kills per minute")
    ax.set_xticks(range(len(table.teammates)), table.teammates)
    labels = [f"{style} {skill}" for style in table.styles for skill in table.skills]
    ax.set_yticks(range(len(rows)), labels, fontsize=8)
    ax.set_xlabel(f"our {table.role}")
    ax.set_ylabel("stand-in partner: style, skill")
    top = max(max(row) for row in means) or 1.0
    for i, partner in enumerate(rows):
        best = table.teammates.index(table.best(partner))
        ax.add_patch(
            Rectangle((best - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2, zorder=BOXES)
        )
        style = table.styles[i // len(table.skills)]
        if p_best and p_best.get(style) in table.teammates:
            j = table.teammates.index(p_best[style])
            box = Rectangle(
                (j - 0.42, i - 0.42), 0.84, 0.84, fill=False, edgecolor="white", linestyle="--", zorder=BOXES
            )
            ax.add_patch(box)
        for j, value in enumerate(means[i]):
            color = "white" if value < top / 2 else "black"
            ax.text(j, i, f"{value:.1f}", ha="center", va="center", color=color, fontsize=7)
    for i in range(len(table.skills), len(rows), len(table.skills)):
        ax.axhline(i - 0.5, color="white", linewidth=1.5, zorder=LINES)
    ax.set_title(
        f"Skill table, {table.role} seat: kills/min over {table.games} games\n"
        "(red: best teammate; dashed: P's best response to the style)",
        fontsize=9,
    )
    return save(fig, path)
