"""Team performance: kills/min of every partner of a population with every static policy of our
role and with adaptive variants, over the same seeds (so results pair by partner and seed), and
`compare`: each adaptive variant against the best single static policy over the population."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from services.evaluation.evaluate import batches, play_games, play_session
from services.evaluation.oracle import chosen_on_other_half
from services.evaluation.results import TeamGame
from services.jobs.core import Spec, spec
from services.jobs.kinds import Runner, in_process
from services.population.adaptive import AdapterConfig
from services.population.human_like import SESSION_TRIALS
from services.population.partners import group_of
from services.population.seat import AdaptiveSeat, SeatSpec, plugins_in
from shared.game import check_role

JOB_GAMES = 256  # games of a team or identification job (the lanes of one batch): tsf eval --job-games
KINDS = {"team": f"{__name__}:run_team_jobs", "session": f"{__name__}:run_session_jobs"}  # for services/jobs
HERE = in_process(KINDS)  # the runner that plays them in this process


def _team_batch(games: list[tuple[str, str, int]], role: str) -> list[list]:
    """Each game's [kills/min, switches, guarded] (the job's names read as seats here, once)."""
    seats = [(SeatSpec.parse(p), SeatSpec.parse(a, "--agent"), seed) for p, a, seed in games]
    played = play_games(seats, role)
    return [[o.kills_per_minute, o.switches, int(o.guarded)] for o in played]


def run_team_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `team` jobs ({role, games: [[partner, agent, seed]...]})."""
    return [
        _team_batch([(p, a, int(seed)) for p, a, seed in job["games"]], check_role(job["role"]))
        for job in args
    ]


def team_jobs(
    role: str, partners: list[str], agents: list[str], seeds: list[int], job_games: int = JOB_GAMES
) -> list[Spec]:
    """Every (partner, agent, seed) game, partner by partner, as jobs of at most `job_games` games."""
    games = [[p, a, s] for p in partners for a in agents for s in seeds]
    plugins = plugins_in(partners)
    parts = batches(games, 1, job_games)
    return [
        spec(f"team-{i}", "team", {"role": role, "games": part}, len(part), plugins)
        for i, part in enumerate(parts)
    ]


def team(
    role: str,
    partners: list[str],
    agents: list[str],
    seeds: list[int],
    run: Runner = HERE,
    progress: Callable[[int, int], None] | None = None,
    job_games: int | None = None,
) -> list[TeamGame]:
    """Kills/min of every (partner, agent, seed); agents are static keys or adaptive variant names.
    The games are jobs (`team_jobs`), run by `run`: here, or on the job system's workers."""
    todo = team_jobs(role, partners, agents, seeds, job_games or JOB_GAMES)
    played = run(todo, progress)
    return [
        TeamGame(partner, agent, seed, kpm, switches, guarded)
        for job, values in zip(todo, played, strict=True)
        for (partner, agent, seed), (kpm, switches, guarded) in zip(job.args["games"], values, strict=True)
    ]


MARGIN = 0.1  # kills/min: the non-inferiority margin against the best static policy


def holm(pvalues: dict[str, float]) -> dict[str, float]:
    """Holm's step-down adjustment of a family of p-values (monotone, capped at 1)."""
    order = sorted(pvalues, key=pvalues.get)
    adjusted, running = {}, 0.0
    for rank, name in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * pvalues[name]))
        adjusted[name] = running
    return adjusted


def paired_tests(diff: np.ndarray, margin: float = MARGIN) -> dict:
    """One-sided paired t-tests of the differences (ours - best static): superiority (mean > 0)
    and non-inferiority (mean > -margin)."""
    from scipy import stats

    def greater(shift: float) -> float:
        if len(diff) < 2 or diff.std(ddof=1) == 0:
            return 0.0 if diff.mean() + shift > 0 else 1.0
        return float(stats.ttest_1samp(diff + shift, 0.0, alternative="greater").pvalue)

    return {
        "mean_difference": float(diff.mean()),
        "stderr": _stderr(diff),
        "p_superior": greater(0.0),
        "p_noninferior": greater(margin),
        "noninferior": greater(margin) < 0.05,
        "n": len(diff),
    }


def _session_games(partner: str, agent: str, person: int, role: str) -> list[list]:
    """Each trial's [seed, kills/min, switches, guarded]."""
    played = play_session(SeatSpec.parse(partner), SeatSpec.parse(agent, "--agent"), person, role)
    seeds = [person * SESSION_TRIALS + trial for trial in range(SESSION_TRIALS)]
    return [
        [seed, o.kills_per_minute, o.switches, int(o.guarded)] for seed, o in zip(seeds, played, strict=True)
    ]


def run_session_jobs(args: list[dict]) -> list[list]:
    """The job system's runner for `session` jobs ({role, partner, agent, person})."""
    return [_session_games(a["partner"], a["agent"], int(a["person"]), check_role(a["role"])) for a in args]


def sessions(
    role: str,
    partners: list[str],
    agents: list[str],
    people: list[int],
    run: Runner = HERE,
    progress: Callable[[int, int], None] | None = None,
) -> list[TeamGame]:
    """`team`, played as sessions: SESSION_TRIALS one-minute trials of each person (seeds
    person * SESSION_TRIALS + trial) with the same partner, an adaptive agent carrying over from
    trial to trial where its strategy has `-memory`. One row per trial; one job per session."""
    plugins = plugins_in(partners)
    todo = [
        spec(
            f"session-{i}",
            "session",
            {"role": role, "partner": p, "agent": a, "person": person},
            SESSION_TRIALS,
            plugins,
        )  # fmt: skip
        for i, (p, a, person) in enumerate((p, a, n) for p in partners for a in agents for n in people)
    ]
    return [
        TeamGame(job.args["partner"], job.args["agent"], seed, kpm, switches, guarded, trial)
        for job, values in zip(todo, run(todo, progress), strict=True)
        for trial, (seed, kpm, switches, guarded) in enumerate(values)
    ]


def _stderr(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def known_partner(
    grid: dict[str, dict[tuple[str, int], float]], statics: list[str], units: list[tuple[str, int]]
) -> np.ndarray:
    """Each game's kills/min with the static policy best for its partner on the partner's other
    games (oracle.py: its seeds alternate between two halves, each scored by the other's choice):
    what choosing one static policy per partner, knowing the partner in advance, would score,
    without the luck of choosing on the games scored."""
    seeds: dict[str, list[int]] = {}
    for partner, seed in units:
        seeds.setdefault(partner, []).append(seed)
    value = {}
    for partner, mine in seeds.items():
        mine.sort()
        kills = np.array([[[grid[a][(partner, s)] for s in mine] for a in statics]])
        value.update(zip(((partner, s) for s in mine), chosen_on_other_half(kills)[0].tolist(), strict=True))
    return np.array([value[u] for u in units])


def compare(
    games: list[TeamGame],
    group_of: Callable[[str], str] = group_of,
    subsets: dict[str, Callable[[str], bool]] | None = None,
) -> dict:
    """Each agent's mean and standard error over the population, and each adaptive variant against
    the best static policy (chosen on this same data, which favours the static side): a one-sided
    paired t-test and a Wilcoxon signed-rank test over (partner, seed) pairs (with Holm's
    correction over the variants), the same t-test over partner means (seeds averaged), the effect
    size d_z = mean difference / sd of differences; per partner group, one-sided superiority and
    non-inferiority (margin MARGIN) tests; each variant's switches per game; and the headroom of
    knowing each partner in advance (`known_partner`) over the best static policy, overall and per
    group: what any rule that picks one of these static policies per partner can gain, and the
    share of it each variant realises. Per variant also how many partners it serves better, as well
    or worse than the best static policy (a partner's mean beyond MARGIN either way), and the share
    of its gain that the top tenth of partners carry. `group_of` names a partner's group (the
    population's groups by default); `subsets` (name -> which partners) gives each variant's
    effect on a part of the population too (`by_subset`, Holm-corrected over variants and parts)."""
    from scipy import stats

    units = sorted({(g.partner, g.seed) for g in games})
    grid: dict[str, dict[tuple[str, int], float]] = {}
    for g in games:
        grid.setdefault(g.agent, {})[(g.partner, g.seed)] = g.kills_per_minute
    values = {a: np.array([g[u] for u in units]) for a, g in grid.items()}
    agents = {a: _summary(v) for a, v in values.items()}
    statics = [a for a in values if not isinstance(SeatSpec.parse(a), AdaptiveSeat)]
    best = max(statics, key=lambda a: agents[a]["mean"])
    partners = sorted({u[0] for u in units})

    def partner_means(a: str) -> np.ndarray:
        return np.array([np.mean([grid[a][u] for u in units if u[0] == p]) for p in partners])

    tests = {}
    for a in values:
        if not isinstance(SeatSpec.parse(a), AdaptiveSeat):
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
            "per_partner": _counts(by_partner),
            "top_tenth_share": _top_share(by_partner),
        }
    holm_p = holm({a: t["p_t"] for a, t in tests.items()})
    for a, t in tests.items():
        t["p_holm"] = holm_p[a]
    group_of_unit = np.array([group_of(u[0]) for u in units])
    known = known_partner(grid, statics, units)

    def headroom(where: np.ndarray) -> dict:
        diff = known[where] - values[best][where]
        return {
            "mean": float(known[where].mean()),
            "mean_difference": float(diff.mean()),
            "stderr": _stderr(diff),
            "percent": float(100 * diff.mean() / base) if (base := values[best][where].mean()) else None,
        }

    by_group = {
        a: {
            g: paired_tests(values[a][group_of_unit == g] - values[best][group_of_unit == g])
            for g in sorted(set(group_of_unit))
        }
        for a in tests
    }
    switching = {}
    for a in tests:
        counts = [g.switches for g in games if g.agent == a]
        switching[a] = {"mean": float(np.mean(counts)), "max": int(max(counts))}
        switching[a]["guarded_games"] = int(sum(g.guarded for g in games if g.agent == a))
    per_partner = {
        p: {a: _summary([grid[a][u] for u in units if u[0] == p]) for a in values} for p in partners
    }
    groups = {group_of(p) for p in partners}
    per_group = {
        g: {a: _summary([grid[a][u] for u in units if group_of(u[0]) == g]) for a in values}
        for g in sorted(groups)
    }
    overall = headroom(np.ones(len(units), dtype=bool))
    for t in tests.values():
        room = overall["mean_difference"]
        t["headroom_realised"] = t["mean_difference"] / room if room > 0 else None
    by_subset: dict[str, dict[str, dict]] = {}
    for name, chosen in (subsets or {}).items():
        where = np.array([chosen(u[0]) for u in units])
        mine = np.array([chosen(p) for p in partners])
        by_subset[name] = {}
        for a in tests:
            diff = values[a][where] - values[best][where]
            by_partner = (partner_means(a) - partner_means(best))[mine]
            by_subset[name][a] = paired_tests(diff) | {
                "percent": float(100 * diff.mean() / values[best][where].mean()),
                "partners": int(mine.sum()),
                "per_partner": _counts(by_partner),
                "known_partner_percent": headroom(where)["percent"],
            }
    subset_p = holm({(n, a): t["p_superior"] for n, by in by_subset.items() for a, t in by.items()})
    for (n, a), p in subset_p.items():
        by_subset[n][a]["p_holm"] = p
    return {
        "units": len(units),
        "partners": len(partners),
        "group_of": {p: group_of(p) for p in partners},
        "by_subset": by_subset,
        "best_static": best,
        "agents": agents,
        "tests": tests,
        "per_partner": per_partner,
        "per_group": per_group,
        "tests_by_group": by_group,
        "switches": switching,
        "margin": MARGIN,
        "known_partner": {
            "all": overall,
            **{g: headroom(group_of_unit == g) for g in sorted(set(group_of_unit))},
        },
    }


def _counts(by_partner: np.ndarray) -> dict[str, int]:
    """How many partners a variant serves better, as well or worse than the best static policy:
    their mean differences beyond MARGIN either way, or within it."""
    return {
        "better": int((by_partner > MARGIN).sum()),
        "equal": int((abs(by_partner) <= MARGIN).sum()),
        "worse": int((by_partner < -MARGIN).sum()),
    }


def _top_share(by_partner: np.ndarray) -> float | None:
    """The share of the total gain over partners that the tenth of them with the largest gains
    carry (None where there is no gain to share)."""
    total = by_partner.sum()
    if total <= 0:
        return None
    top = np.sort(by_partner)[::-1][: max(1, math.ceil(len(by_partner) / 10))]
    return float(top.sum() / total)


def _summary(values: list[float]) -> dict:
    array = np.array(values)
    return {"mean": float(array.mean()), "stderr": _stderr(array), "n": len(array)}


def variants(
    windows: list[int], strategies: list[str], strategy_window: int = AdapterConfig.window
) -> list[str]:
    """The study's CEM at every window, and every other strategy at `strategy_window`."""
    names = [AdapterConfig(window=w, strategy="cem").name for w in windows]
    names += [AdapterConfig(window=strategy_window, strategy=s).name for s in strategies if s != "cem"]
    return list(dict.fromkeys(names))
