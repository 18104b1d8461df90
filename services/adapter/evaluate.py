"""Evaluating the adaptive agent in-process: is the partner identified, and does adapting help?

- `identification`: library partners with 10 % action noise play with our best response to them;
  at every frame with a full window, is the most similar library policy the true one? Also the
  confusion matrix, and how many frames the estimate takes to follow a partner that switched.
- `team`: kills/min of every partner of a population with every static policy of our role and
  with adaptive variants, over the same seeds (so results pair by partner and seed).
- `compare`: each adaptive variant against the best single static policy over the population.
- `calibrate`: the out-of-library thresholds (calibration.json).

Games are the same core as everywhere (engine, library policies, the adapter core); the adaptive
agent switches as the agent service does: from the frame after the adapter's choice, with the
policy reset by `switch_seed`. Work is spread over processes, each with its own loaded library.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cache
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from services.adapter.cem import log_probs
from services.adapter.core import (
    CALIBRATION,
    Adapter,
    AdapterConfig,
    Payoff,
    Scorer,
)
from services.adapter.partners import SWITCH_AT, Noisy, Partner, Switching, group_of, make_partner
from services.agent import library
from services.sim.engine import Game
from services.sim.observation import observe, world_values
from services.sim.play import policy_seed, switch_seed
from services.table.table import DEFAULT_TABLE
from shared.game import ROLES, GameConfig, Policy, bait_first, other

FOLLOW_HOLD = 30  # frames the estimate must stay on the new type to count as following it


@dataclass(frozen=True)
class Setup:
    """What games of one adaptive seat need, loaded once per process."""

    role: str
    payoff: Payoff
    scorer: Scorer
    ours: dict[str, Policy]


@cache
def setup(role: str, table: Path = DEFAULT_TABLE) -> Setup:
    payoff = Payoff.load(role, table)
    scorer = Scorer([library.load(k) for k in payoff.partners])
    return Setup(role, payoff, scorer, {k: library.load(k) for k in payoff.ours})


@dataclass
class Outcome:
    """One game: the team's score, and for an adaptive agent its choices over time."""

    kills_per_minute: float
    switches: int = 0
    timeline: list[tuple[int, str, str]] = field(default_factory=list)  # (frame, estimate, policy)
    values: list[list[float]] = field(default_factory=list)  # the partner's world-frame states
    actions: list[int] = field(default_factory=list)  # and actions, when recorded


def play_partner(
    partner: Partner,
    agent: str | AdapterConfig,
    seed: int,
    role: str,
    config: GameConfig | None = None,
    record: bool = False,
) -> Outcome:
    """One game of `partner` with our seat `role` played by a static library key or adaptively."""
    s, partner_role = setup(role), other(role)
    game = Game(config, seed)
    partner.reset(policy_seed(seed, partner_role))
    adapter = None
    if isinstance(agent, AdapterConfig):
        adapter = agent.build(s.payoff)
        agent = adapter.policy
    ours = s.ours[agent]
    ours.reset(policy_seed(seed, role))
    outcome = Outcome(0.0)
    while not game.done:
        partner_action = partner.act(observe(game, partner_role, partner.frame))
        our_action = ours.act(observe(game, role, ours.frame))
        if adapter is not None or record:
            values = world_values(game, partner_role)
        if record:
            outcome.values.append(values)
            outcome.actions.append(partner_action)
        if adapter is not None and adapter.update(s.scorer(values, partner_action)):
            ours = s.ours[adapter.policy]
            ours.reset(switch_seed(seed, role, game.frame + 1))
            outcome.switches += 1
            outcome.timeline.append((game.frame + 1, adapter.partner, adapter.policy))
        pair = bait_first(partner_role, partner_action, our_action)
        game.step(*pair)
    outcome.kills_per_minute = game.kills_per_minute()
    return outcome


# --- parallel running ------------------------------------------------------------------------------


def run_parallel(
    fn: Callable, tasks: list[tuple], workers: int, progress: Callable[[int, int], None] | None = None
) -> list:
    """fn(*task) for every task, over `workers` processes (in this process when workers <= 1)."""
    results = []
    if workers <= 1:
        for task in tasks:
            results.append(fn(*task))
            if progress:
                progress(len(results), len(tasks))
        return results
    with get_context("fork").Pool(workers) as pool:
        for result in pool.imap(_star, [(fn, task) for task in tasks], chunksize=1):
            results.append(result)
            if progress:
                progress(len(results), len(tasks))
    return results


def _star(job: tuple[Callable, tuple]) -> object:
    fn, task = job
    return fn(*task)


# --- team performance --------------------------------------------------------------------------


def _team_game(partner: str, agent: str, seed: int, role: str) -> dict:
    config = AdapterConfig.parse(agent, role=role)
    outcome = play_partner(make_partner(partner, other(role)), config or agent, seed, role)
    return {
        "partner": partner,
        "agent": agent,
        "seed": seed,
        "kills_per_minute": outcome.kills_per_minute,
        "switches": outcome.switches,
    }


def team(
    role: str,
    partners: list[str],
    agents: list[str],
    seeds: list[int],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """Kills/min of every (partner, agent, seed); agents are static keys or adaptive variant names."""
    tasks = [(p, a, s, role) for p in partners for a in agents for s in seeds]
    return run_parallel(_team_game, tasks, workers, progress)


def _stderr(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def compare(rows: list[dict]) -> dict:
    """Each agent's mean and standard error over the population, and each adaptive variant against
    the best static policy (chosen on this same data, which favours the static side): a one-sided
    paired t-test and a Wilcoxon signed-rank test over (partner, seed) pairs, the same t-test over
    partner means (seeds averaged), and the effect size d_z = mean difference / sd of differences."""
    from scipy import stats

    units = sorted({(r["partner"], r["seed"]) for r in rows})
    grid: dict[str, dict[tuple[str, int], float]] = {}
    for r in rows:
        grid.setdefault(r["agent"], {})[(r["partner"], r["seed"])] = r["kills_per_minute"]
    values = {a: np.array([g[u] for u in units]) for a, g in grid.items()}
    agents = {a: _summary(v) for a, v in values.items()}
    statics = [a for a in values if AdapterConfig.parse(a) is None]
    best = max(statics, key=lambda a: agents[a]["mean"])
    partners = sorted({u[0] for u in units})

    def partner_means(a: str) -> np.ndarray:
        return np.array([np.mean([grid[a][u] for u in units if u[0] == p]) for p in partners])

    tests = {}
    for a in values:
        if AdapterConfig.parse(a) is None:
            continue
        diff = values[a] - values[best]
        by_partner = partner_means(a) - partner_means(best)
        nonzero = diff[diff != 0]
        tests[a] = {
            "mean_difference": float(diff.mean()),
            "stderr": _stderr(diff),
            "d_z": float(diff.mean() / diff.std(ddof=1)) if diff.std(ddof=1) > 0 else 0.0,
            "t": float(stats.ttest_rel(values[a], values[best]).statistic),
            "p_t": float(stats.ttest_rel(values[a], values[best], alternative="greater").pvalue),
            "p_wilcoxon": float(stats.wilcoxon(nonzero, alternative="greater").pvalue)
            if len(nonzero)
            else 1.0,
            "p_t_partners": float(stats.ttest_1samp(by_partner, 0.0, alternative="greater").pvalue),
            "partners_better": int((by_partner > 0).sum()),
            "partners": len(partners),
        }
    per_partner = {
        p: {a: _summary([grid[a][u] for u in units if u[0] == p]) for a in values} for p in partners
    }
    groups = {group_of(p) for p in partners}
    per_group = {
        g: {a: _summary([grid[a][u] for u in units if group_of(u[0]) == g]) for a in values}
        for g in sorted(groups)
    }
    return {
        "units": len(units),
        "partners": len(partners),
        "best_static": best,
        "agents": agents,
        "tests": tests,
        "per_partner": per_partner,
        "per_group": per_group,
    }


def _summary(values: list[float]) -> dict:
    array = np.array(values)
    return {"mean": float(array.mean()), "stderr": _stderr(array), "n": len(array)}


# --- identification ------------------------------------------------------------------------------


def windowed(scores: np.ndarray, window: int) -> np.ndarray:
    """Means over every full window of `window` frames: row i covers frames i .. i + window - 1."""
    sums = np.cumsum(np.vstack([np.zeros(scores.shape[1]), scores]), axis=0)
    return (sums[window:] - sums[:-window]) / window


def bayes_estimates(scores: np.ndarray, config: AdapterConfig, payoff: Payoff) -> np.ndarray:
    """The Bayesian filter's most likely type at every frame (the same code the adapter runs)."""
    adapter = Adapter(config, payoff)
    estimates = np.empty(len(scores), dtype=int)
    for t, row in enumerate(scores):
        adapter.forward(row)
        estimates[t] = int(np.argmax(adapter.log_belief))
    return estimates


def _stream(partner: str, teammate: str, seed: int, role: str) -> np.ndarray:
    """Scores of a noisy partner's frames (rows) under each library policy of its role (columns)."""
    s = setup(role)
    outcome = play_partner(Noisy(make_partner(partner, other(role))), teammate, seed, role, record=True)
    return s.scorer.batch(np.array(outcome.values), np.array(outcome.actions))


def switch_scores(first: str, second: str, seed: int, role: str) -> np.ndarray:
    """Scores of a noisy partner that switches from `first` to `second` at SWITCH_AT, playing with
    our best response to `first` (what the adaptive agent plays before the switch)."""
    s, partner_role = setup(role), other(role)
    teammate = s.payoff.ours[s.payoff.best_response(s.payoff.partners.index(first))]
    switching = Switching(make_partner(first, partner_role), make_partner(second, partner_role))
    outcome = play_partner(Noisy(switching), teammate, seed, role, record=True)
    return s.scorer.batch(np.array(outcome.values), np.array(outcome.actions))


def follow_lag(estimates: np.ndarray, target: int, start: int, hold: int = FOLLOW_HOLD) -> int | None:
    """Frames from `start` until the estimate is `target` and stays so for `hold` frames (or to the end)."""
    run = 0
    for t in range(start, len(estimates)):
        run = run + 1 if estimates[t] == target else 0
        if run >= hold or (run and t == len(estimates) - 1):
            return t - run + 1 - start
    return None


def identification(
    role: str,
    windows: list[int],
    seeds: list[int],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Identification of library partners (10 % action noise) by the CEM window and by the filter."""
    s = setup(role)
    keys = list(s.payoff.partners)
    teammate = {k: s.payoff.ours[s.payoff.best_response(i)] for i, k in enumerate(keys)}
    pairs = [(a, b) for a in keys for b in keys if a != b]
    tasks = [(k, teammate[k], seed, role) for k in keys for seed in seeds]
    switch_tasks = [(a, b, seed, role) for a, b in pairs for seed in seeds[:1]]
    total = len(tasks) + len(switch_tasks)
    streams = run_parallel(_stream, tasks, workers, progress and (lambda d, _: progress(d, total)))
    switched = run_parallel(
        switch_scores, switch_tasks, workers, progress and (lambda d, _: progress(len(tasks) + d, total))
    )
    out: dict = {"partners": keys, "seeds": seeds, "noise": 0.1, "windows": {}}
    for window in windows:
        confusion = np.zeros((len(keys), len(keys)), dtype=int)
        bayes_right = bayes_total = 0
        config = AdapterConfig(role, window, "bayes")
        for (key, *_), scores in zip(tasks, streams, strict=True):
            estimates = windowed(scores, window).argmax(axis=1)
            np.add.at(confusion[keys.index(key)], estimates, 1)
            bayes = bayes_estimates(scores, config, s.payoff)[window - 1 :]
            bayes_right += int((bayes == keys.index(key)).sum())
            bayes_total += len(bayes)
        lags, bayes_lags = [], []
        for (_, second, *_), scores in zip(switch_tasks, switched, strict=True):
            target = keys.index(second)
            estimates = np.concatenate([np.full(window - 1, -1), windowed(scores, window).argmax(axis=1)])
            lags.append(follow_lag(estimates, target, SWITCH_AT))
            bayes_lags.append(follow_lag(bayes_estimates(scores, config, s.payoff), target, SWITCH_AT))
        out["windows"][window] = {
            "accuracy": float(np.trace(confusion) / confusion.sum()),
            "bayes_accuracy": bayes_right / bayes_total,
            "confusion": confusion.tolist(),
            "follow": _lag_summary(lags, window),
            "bayes_follow": _lag_summary(bayes_lags, window),
        }
    return out


def _lag_summary(lags: list[int | None], window: int) -> dict:
    followed = [lag for lag in lags if lag is not None]
    return {
        "switches": len(lags),
        "followed": len(followed),
        "median_frames": float(np.median(followed)) if followed else None,
        "within_half_window": sum(lag <= window / 2 for lag in followed) / len(lags) if lags else 0.0,
    }


# --- out-of-library calibration --------------------------------------------------------------------


def _self_scores(key: str, teammate: str, seed: int) -> np.ndarray:
    """log pi(a | s) of a library policy's own actions over one game with `teammate`."""
    policy = library.load(key)
    partner_role = other(policy.role)
    outcome = play_partner(make_partner(key, policy.role), teammate, seed, partner_role, record=True)
    return log_probs([policy], outcome.values, outcome.actions)[:, 0]


def calibrate(
    windows: Iterable[int] = (100, 150, 200, 300, 400, 600, 800, 1000),
    seeds: list[int] | None = None,
    quantile: float = 0.01,
    margin: float = 2.0,
    workers: int = 1,
) -> dict:
    """Out-of-library thresholds: for each role and window T, the lowest (over library policies)
    `quantile` of a policy's own mean log-probability over T-frame windows of its play with every
    library policy of the other role, minus `margin` nats. A partner whose best similarity is
    below it explains its actions far worse than any library policy explains its own."""
    seeds = seeds or [0, 1]
    tasks = [
        (k, mate, seed)
        for k in library.registry()
        for mate in library.keys(other(_role(k)))
        for seed in seeds
    ]
    streams = run_parallel(_self_scores, tasks, workers)
    thresholds: dict[str, dict[str, float]] = {role: {} for role in ROLES}
    lowest: dict[str, dict[str, dict[str, float]]] = {role: {} for role in ROLES}
    for window in windows:
        means = [windowed(s[:, None], window)[:, 0] for s in streams]
        for role in ROLES:
            per_policy = {}
            for k in library.keys(role):
                mine = np.concatenate([m for (key, *_), m in zip(tasks, means, strict=True) if key == k])
                per_policy[k] = float(np.quantile(mine, quantile))
            lowest[role][str(window)] = per_policy
            thresholds[role][str(window)] = min(per_policy.values()) - margin
    return {
        "quantile": quantile,
        "margin": margin,
        "seeds": seeds,
        "library": library.manifest_hash(),
        "thresholds": thresholds,
        "self_quantiles": lowest,
    }


def _role(key: str) -> str:
    return library.registry()[key].role


def write_calibration(result: dict, path: Path = CALIBRATION) -> Path:
    path.write_text(json.dumps(result, indent=1) + "\n")
    return path


def variants(
    windows: list[int], strategies: list[str], strategy_window: int = AdapterConfig.window
) -> list[str]:
    """The study's CEM at every window, and every other strategy at `strategy_window`."""
    names = [AdapterConfig(window=w, strategy="cem").name for w in windows]
    names += [AdapterConfig(window=strategy_window, strategy=s).name for s in strategies if s != "cem"]
    return list(dict.fromkeys(names))


def _csv(path: Path, header: list[str], rows: Iterable[Iterable]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)


def _group_table(comparison: dict) -> list[str]:
    groups = list(comparison["per_group"])
    agents = sorted(comparison["agents"], key=lambda a: (AdapterConfig.parse(a) is not None, a))
    rows = [
        f"| {a} | " + " | ".join(f"{comparison['per_group'][g][a]['mean']:.2f}" for g in groups) + " |"
        for a in agents
    ]
    return ["| agent | " + " | ".join(groups) + " |", "| --- |" + " --- |" * len(groups), *rows]


def write_results(
    out: Path, identification_result: dict | None, rows: list[dict], comparison: dict | None
) -> Path:
    """Every number behind the figures, as JSON and CSV, and a Markdown summary (summary.md)."""
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Adapter evaluation", ""]
    if identification_result:
        (out / "identification.json").write_text(json.dumps(identification_result, indent=1) + "\n")
        keys = identification_result["partners"]
        lines += [
            "## Identification (library partners, 10 % action noise)",
            "",
            "| T | CEM accuracy | filter accuracy | CEM follows within T/2 | median frames to follow |",
            "| --- | --- | --- | --- | --- |",
        ]
        for window, r in identification_result["windows"].items():
            confusion = ([k, *row] for k, row in zip(keys, r["confusion"], strict=True))
            _csv(out / f"confusion_T{window}.csv", ["true \\ estimated", *keys], confusion)
            follow = r["follow"]
            lines.append(
                f"| {window} | {r['accuracy']:.3f} | {r['bayes_accuracy']:.3f} | "
                f"{follow['within_half_window']:.2f} ({follow['followed']}/{follow['switches']} followed) | "
                f"{follow['median_frames']} |"
            )
        lines.append("")
    if rows:
        _csv(out / "team.csv", list(rows[0]), (r.values() for r in rows))
    if comparison:
        (out / "comparison.json").write_text(json.dumps(comparison, indent=1) + "\n")
        agents = comparison["agents"]
        _csv(
            out / "per_partner.csv",
            ["partner", "group", "agent", "kills_per_minute", "stderr", "games"],
            (
                [p, group_of(p), a, f"{v['mean']:.4f}", f"{v['stderr']:.4f}", v["n"]]
                for p, by_agent in comparison["per_partner"].items()
                for a, v in by_agent.items()
            ),
        )
        lines += [
            f"## Team performance ({comparison['partners']} partners, {comparison['units']} games per agent)",
            "",
            "| agent | kills/min | s.e. |",
            "| --- | --- | --- |",
            *(f"| {a} | {v['mean']:.3f} | {v['stderr']:.3f} |" for a, v in sorted(agents.items())),
            "",
            "Mean kills/min by partner group (every partner: per_partner.csv):",
            "",
            *_group_table(comparison),
            "",
            f"Best static policy: **{comparison['best_static']}**.",
            "",
            "| adaptive | difference | d_z | p (paired t) | p (Wilcoxon) | p (partners) | partners better |",
            "| --- | --- | --- | --- | --- | --- | --- |",
            *(
                f"| {a} | {t['mean_difference']:+.3f} ± {t['stderr']:.3f} | {t['d_z']:+.3f} | "
                f"{t['p_t']:.3g} | {t['p_wilcoxon']:.3g} | {t['p_t_partners']:.3g} | "
                f"{t['partners_better']}/{t['partners']} |"
                for a, t in comparison["tests"].items()
            ),
            "",
        ]
    path = out / "summary.md"
    path.write_text("\n".join(lines))
    return path
