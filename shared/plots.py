"""What every figure of the project shares: saving, placing point labels where they collide with no
other text, and the check that no two texts of a drawn figure overlap and none is cut off by its
edge (the report's and the evaluation's tests run it on every figure they draw)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.text import Text  # noqa: E402
from matplotlib.transforms import Bbox  # noqa: E402

# Offsets (points) tried in turn for a point's label: beside it first, then farther out.
OFFSETS = tuple(
    (dx * r, dy * r)
    for r in (1, 2, 3, 4)
    for dx, dy in ((4, 4), (4, -10), (-4, 4), (-4, -10), (6, -3), (-6, -3), (0, 8), (0, -14))
)


_checked: list[plt.Figure] | None = None  # while `drawn` runs: the figures saved, kept open


def save(fig: plt.Figure, path: Path, dpi: int = 100) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    fig.set_label(str(path))
    if _checked is None:
        plt.close(fig)
    else:
        _checked.append(fig)
    return path


def drawn(draw: Callable[[], object]) -> list[plt.Figure]:
    """Run `draw`, which saves figures through `save`, and return them open, as saved (the caller
    closes them): for checks of what a figure shows."""
    global _checked
    _checked = []
    try:
        draw()
        return list(_checked)
    finally:
        _checked = None


def legibility(draw: Callable[[], object]) -> dict[str, list[str]]:
    """The `text_problems` of every figure `draw` saves, by file name (none: every label legible)."""
    figures = drawn(draw)
    try:
        return {Path(fig.get_label()).name: text_problems(fig) for fig in figures}
    finally:
        for fig in figures:
            plt.close(fig)


def texts(fig: plt.Figure) -> list[tuple[Text, Bbox]]:
    """Every text the drawn figure shows, with its extent in display pixels: visible and non-empty,
    and for tick labels only those of ticks inside the axis's view (matplotlib keeps, but does not
    draw, the labels of ticks beyond it)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ticks, shown = set(), []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            low, high = sorted(axis.get_view_interval())
            span = (high - low) * 1e-9
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                ticks.update({id(tick.label1), id(tick.label2)})
                if low - span <= tick.get_loc() <= high + span:
                    shown += [tick.label1, tick.label2]
    candidates = [t for t in fig.findobj(Text) if id(t) not in ticks] + shown
    return [
        (text, text.get_window_extent(renderer))
        for text in dict.fromkeys(candidates)
        if text.get_visible() and text.get_text().strip()
    ]


def text_problems(fig: plt.Figure, slack: float = 0.5) -> list[str]:
    """Pairs of texts whose extents intersect, and texts that reach past the figure's edge (each by
    its words); empty for a legible figure. `slack` pixels of touching are allowed."""
    placed = texts(fig)
    edge = fig.bbox
    problems = []
    for i, (text, box) in enumerate(placed):
        name = repr(text.get_text())
        if (
            box.x0 < edge.x0 - slack
            or box.y0 < edge.y0 - slack
            or box.x1 > edge.x1 + slack
            or box.y1 > edge.y1 + slack
        ):
            problems.append(f"{name} is cut off by the figure's edge")
        for other, other_box in placed[i + 1 :]:
            if _overlap(box, other_box, slack):
                problems.append(f"{name} overlaps {other.get_text()!r}")
    return problems


def place_labels(
    ax: plt.Axes,
    points: Sequence[tuple[float, float]],
    labels: Sequence[str],
    fontsize: float = 8,
    color: str = "black",
) -> None:
    """Annotate each point with its label at the first offset (OFFSETS) where the label meets no
    text already in the figure and stays inside the axes; where none is free, the last tried."""
    fig = ax.figure
    taken = [box for _, box in texts(fig)]
    inside = ax.get_window_extent()
    for (x, y), label in zip(points, labels, strict=True):
        note = None
        for dx, dy in OFFSETS:
            if note is not None:
                note.remove()
            note = ax.annotate(
                label, (x, y), textcoords="offset points", xytext=(dx, dy), fontsize=fontsize, color=color
            )
            box = note.get_window_extent(fig.canvas.get_renderer())
            fits = inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1
            if fits and not any(_overlap(box, other, 0.0) for other in taken):
                break
        taken.append(note.get_window_extent(fig.canvas.get_renderer()))


def _overlap(a: Bbox, b: Bbox, slack: float) -> bool:
    return a.x0 < b.x1 - slack and b.x0 < a.x1 - slack and a.y0 < b.y1 - slack and b.y0 < a.y1 - slack
