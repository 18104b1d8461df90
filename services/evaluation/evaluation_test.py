"""The evaluation as one function: a plan's defaults and checks, and one small evaluation in-process
with its report written."""

from __future__ import annotations

import csv
import json

import pytest

from services.agent import library
from services.evaluation.evaluation import EvalPlan, evaluate
from services.population.adaptive import STRATEGIES
from services.population.partners import population
from shared.errors import UsageError


def test_a_plan_without_partners_plays_the_population_and_checks_every_partner() -> None:
    plan = EvalPlan("bait", windows=(150,), strategies=("cem", "bayes"), strategy_window=400)
    assert plan.partners == tuple(p for group in population("shooter").values() for p in group)
    assert plan.agents == [*library.keys("bait"), "adaptive-T150-cem", "adaptive-T400-bayes"]
    with pytest.raises(UsageError, match="nope"):
        EvalPlan("shooter", partners=("B1", "nope(B1)"))


def test_a_plan_names_a_skill_strategy_only_where_its_model_fits_and_refuses_one_asked_for() -> None:
    skill = "bayes-dwell-ood-guard-skill"  # the shipped skill model: shooter seat, T = 400
    assert EvalPlan("shooter", ("B1",)).strategies == STRATEGIES
    assert EvalPlan("bait", ("S1",)).strategies == tuple(s for s in STRATEGIES if s != skill)
    assert skill not in EvalPlan("shooter", ("B1",), strategy_window=150).strategies
    with pytest.raises(UsageError, match=f"--strategy {skill}: .* seat shooter, not bait"):
        EvalPlan("bait", ("S1",), strategies=(skill,))


def test_an_evaluation_plays_every_partner_with_every_agent_and_writes_its_report(tmp_path) -> None:
    plan = EvalPlan(
        "shooter", ("B1", "noisy(B5)"), seeds=2, windows=(150,), strategies=("cem",), identify=False
    )
    steps: list[str] = []
    report = evaluate(plan, progress=lambda step: steps.append(step) or (lambda done, total: None))
    assert steps == ["team games"] and report.identification is None and report.curves is None
    agents = plan.agents
    assert [(g.partner, g.agent, g.seed) for g in report.games] == [
        (p, a, s) for p in plan.partners for a in agents for s in (0, 1)
    ]
    adaptive = [g for g in report.games if g.agent == "adaptive-T150-cem"]
    assert all(g.switches >= 1 for g in adaptive)  # every game left the initial policy
    assert report.comparison["best_static"] in agents and report.comparison["units"] == 4
    summary = report.write(tmp_path)
    with (tmp_path / "team.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["partner", "agent", "seed", "kills_per_minute", "switches", "guarded"]
    assert [float(r["kills_per_minute"]) for r in rows] == [g.kills_per_minute for g in report.games]
    assert json.loads((tmp_path / "comparison.json").read_text()) == report.comparison
    assert (tmp_path / "adaptive_vs_static.png").stat().st_size > 0 and "Best static" in summary.read_text()
