"""The evaluation's figures, drawn from the shipped results (docs/eval) and checked as rendered: the
headline figure shows each adaptive agent's difference from the best static policy with its
standard error and marks the shipped default agent; no text overlaps another or is cut off."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from services.evaluation import figures
from services.evaluation.results import Comparison
from services.population.adaptive import ADAPTIVE, SHIPPED
from shared.plots import drawn, legibility

EVAL = Path(__file__).resolve().parents[2] / "docs" / "eval"


@pytest.fixture
def shipped(tmp_path: Path) -> Path:
    for name in ("identification.json", "comparison.json"):
        shutil.copy(EVAL / name, tmp_path / name)
    return tmp_path


def test_the_headline_figure_draws_differences_from_the_best_static_policy(shipped: Path) -> None:
    """On the held-out shooter evaluation, where the shipped default agent is one of the agents."""
    held_out = EVAL / "held-out" / "shooter" / "comparison.json"
    comparison = Comparison.of(json.loads(held_out.read_text()))
    [fig] = drawn(lambda: figures.adaptive_vs_static(comparison, shipped / "adaptive_vs_static.png"))
    try:
        [ax] = fig.axes
        tests = comparison.tests
        widths = [bar.get_width() for bar in ax.patches]
        assert widths == pytest.approx([t["mean_difference"] for t in tests.values()])
        low, high = ax.get_xlim()
        assert low < min(0, *widths) and max(0, *widths) < high  # bars from zero, either way
        labels = [t.get_text() for t in ax.get_yticklabels()]
        default = SHIPPED.name
        marked = [label for label in labels if "(default)" in label]
        assert marked == [default.removeprefix(ADAPTIVE) + " (default)"]
        bold = [t.get_text() for t in ax.get_yticklabels() if t.get_fontweight() == "bold"]
        assert bold == marked
        best = comparison.best_static
        assert best in ax.get_xlabel() and "s.e." in ax.get_xlabel()
        for name, test in tests.items():  # each bar's label: the difference, its s.e. and the per cent
            share = 100 * test["mean_difference"] / comparison.base
            text = f"{test['mean_difference']:+.3f} ± {test['stderr']:.3f} ({share:+.1f} %)"
            assert text in [t.get_text() for t in ax.texts], name
    finally:
        plt.close(fig)


def test_no_label_of_an_evaluation_figure_overlaps_another_or_is_cut_off(shipped: Path) -> None:
    rng = np.random.default_rng(0)
    scores = np.log(rng.dirichlet(np.ones(12), size=(900, 9))[:, :, 0])
    keys = [f"B{i}" for i in range(1, 10)]

    def draw() -> None:
        figures.redraw(shipped)
        title = "Partner noisy(switch(B1,B5)), switching at 15 s"
        figures.logprob_curves(scores, keys, 150, title, shipped / "logprob_curves.png", 450)

    checked = legibility(draw)
    assert set(checked) == {"identification.png", "adaptive_vs_static.png", "logprob_curves.png"}
    assert {name: problems for name, problems in checked.items() if problems} == {}


def test_the_shipped_figures_are_drawn_from_the_shipped_numbers(shipped: Path) -> None:
    """docs/eval's two figures from data are what `redraw` draws from its JSON now (same pixels)."""
    from PIL import Image, ImageChops

    figures.redraw(shipped)
    for name in ("identification.png", "adaptive_vs_static.png"):
        with Image.open(EVAL / name) as shipped_image, Image.open(shipped / name) as fresh:
            assert shipped_image.size == fresh.size
            assert ImageChops.difference(shipped_image.convert("RGB"), fresh.convert("RGB")).getbbox() is None
