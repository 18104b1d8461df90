"""The evaluation as one function: a plan's defaults and checks, and one small evaluation in-process
with its report written."""

from __future__ import annotations

import csv
import json

import pytest

from services.agent import library
from services.evaluation import held_out
from services.evaluation.evaluation import EvalPlan, evaluate
from services.evaluation.populations import listed, named
from services.population.adaptive import STRATEGIES, AdapterConfig
from services.population.partners import population
from shared.errors import UsageError


def test_a_plan_without_partners_plays_the_population_and_checks_every_partner() -> None:
    plan = EvalPlan("bait", windows=(150,), strategies=("cem", "bayes"), strategy_window=400)
    assert plan.partners == tuple(p for kind in population("shooter").values() for p in kind)
    assert plan.population.name == "default" and plan.variants  # strategies asked: the study's variants
    assert plan.agents == [*library.keys("bait"), "adaptive-T150-cem", "adaptive-T400-bayes"]
    with pytest.raises(UsageError, match="nope"):
        EvalPlan("shooter", listed(("B1", "nope(B1)"), "bait"))


@pytest.mark.parametrize("name", ["default", "held-out"])
def test_a_plan_compares_what_ships_whatever_the_population(name: str) -> None:
    """The static policies of every shipped library, the shipped default agent and the study's:
    the population is the one thing chosen."""
    plan = EvalPlan("shooter", named(name, "bait"))
    shipped = [AdapterConfig(partners="groups").name, AdapterConfig(partners="library").name]
    assert plan.agents == [*held_out.statics("shooter"), *shipped] and {"S4", "GS1"} <= set(plan.agents)
    assert AdapterConfig.shipped().name == shipped[0] and plan.population.name == name
    assert plan.population.parts == ("group" if name == "held-out" else "kind")


def test_a_plan_names_a_skill_strategy_only_where_its_model_fits_and_refuses_one_asked_for() -> None:
    skill = "bayes-dwell-ood-guard-skill"  # the shipped skill model: shooter seat, T = 400
    b1, s1 = listed(("B1",), "bait"), listed(("S1",), "shooter")
    assert EvalPlan("shooter", b1, variants=True).strategies == STRATEGIES
    assert EvalPlan("bait", s1, variants=True).strategies == tuple(s for s in STRATEGIES if s != skill)
    assert skill not in EvalPlan("shooter", b1, strategy_window=150, variants=True).strategies
    with pytest.raises(UsageError, match=f"--strategy {skill}: .* seat shooter, not bait"):
        EvalPlan("bait", s1, strategies=(skill,))


def test_an_evaluation_plays_every_partner_with_every_agent_and_writes_its_report(tmp_path) -> None:
    partners = listed(("B1", "noisy(B5)"), "bait")
    plan = EvalPlan("shooter", partners, seeds=2, windows=(150,), strategies=("cem",), identify=False)
    steps: list[str] = []
    report = evaluate(plan, progress=lambda step: steps.append(step) or (lambda done, total: None))
    assert steps == ["team games"] and report.identification is None and report.curves is None
    agents = plan.agents
    assert [(g.partner, g.agent, g.seed) for g in report.games] == [
        (p, a, s) for p in plan.partners for a in agents for s in (0, 1)
    ]
    adaptive = [g for g in report.games if g.agent == "adaptive-T150-cem"]
    assert all(g.switches >= 1 for g in adaptive)  # every game left the initial policy
    assert report.comparison.best_static in agents and report.comparison.units == 4
    summary = report.write(tmp_path)
    with (tmp_path / "team.csv").open() as f:
        rows = list(csv.DictReader(f))
    header = ["partner", "agent", "seed", "kills_per_minute", "switches", "guarded", "population"]
    assert list(rows[0]) == header and {r["population"] for r in rows} == {"listed"}
    assert [float(r["kills_per_minute"]) for r in rows] == [g.kills_per_minute for g in report.games]
    assert json.loads((tmp_path / "comparison.json").read_text()) == report.comparison.to_json()
    assert report.comparison.population == "listed" and "Population: listed." in summary.read_text()
    assert (tmp_path / "adaptive_vs_static.png").stat().st_size > 0 and "Best static" in summary.read_text()
