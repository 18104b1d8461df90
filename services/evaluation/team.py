"""Team performance: kills/min of every partner of a population with every static policy of our
role and with adaptive variants, over the same seeds (so results pair by partner and seed), and
`compare`: each adaptive variant against the best single static policy over the population."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.agent import library
from services.evaluation import held_out
from services.evaluation.evaluate import batches, play_games, play_session
from services.evaluation.oracle import chosen_on_other_half
from services.evaluation.populations import Population, listed
from services.evaluation.results import BEST, PREVIOUS, SCORING, STUDY, Comparison, TeamGame, percent
from services.jobs.core import Spec, spec
from services.jobs.kinds import Runner, in_process
from services.population.adaptive import AdapterConfig
from services.population.human_like import SESSION_TRIALS
from services.population.seat import AdaptiveSeat, SeatSpec, plugins_in
from shared.game import ROLES, check_role, other

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


@dataclass(frozen=True)
class _Paired:
    """Every agent's kills/min over the same (partner, seed) units, and the best static policy."""

    units: list[tuple[str, int]]
    grid: dict[str, dict[tuple[str, int], float]]  # agent -> unit -> kills/min
    values: dict[str, np.ndarray]  # agent -> kills/min in the order of `units`
    statics: list[str]
    best: str
    partners: list[str]

    @classmethod
    def of(cls, games: list[TeamGame]) -> _Paired:
        units = sorted({(g.partner, g.seed) for g in games})
        grid: dict[str, dict[tuple[str, int], float]] = {}
        for g in games:
            grid.setdefault(g.agent, {})[(g.partner, g.seed)] = g.kills_per_minute
        values = {a: np.array([g[u] for u in units]) for a, g in grid.items()}
        statics = [a for a in values if not isinstance(SeatSpec.parse(a), AdaptiveSeat)]
        best = max(statics, key=lambda a: float(values[a].mean()))
        return cls(units, grid, values, statics, best, sorted({u[0] for u in units}))

    @property
    def adaptive(self) -> list[str]:
        return [a for a in self.values if a not in self.statics]

    def partner_means(self, agent: str) -> np.ndarray:
        return np.array(
            [np.mean([self.grid[agent][u] for u in self.units if u[0] == p]) for p in self.partners]
        )

    def difference(self, agent: str) -> np.ndarray:
        return self.values[agent] - self.values[self.best]

    def by_partner(self, agent: str) -> np.ndarray:
        return self.partner_means(agent) - self.partner_means(self.best)


def _test(paired: _Paired, a: str) -> dict:
    """One adaptive variant against the best static policy over every (partner, seed) pair."""
    from scipy import stats

    ours, best = paired.values[a], paired.values[paired.best]
    diff, by_partner = paired.difference(a), paired.by_partner(a)
    nonzero = diff[diff != 0]
    return {
        "mean_difference": float(diff.mean()),
        "stderr": _stderr(diff),
        "d_z": float(diff.mean() / diff.std(ddof=1)) if diff.std(ddof=1) > 0 else 0.0,
        "t": float(stats.ttest_rel(ours, best).statistic),
        "p_t": float(stats.ttest_rel(ours, best, alternative="greater").pvalue),
        "p_wilcoxon": float(stats.wilcoxon(nonzero, alternative="greater").pvalue) if len(nonzero) else 1.0,
        "p_t_partners": float(stats.ttest_1samp(by_partner, 0.0, alternative="greater").pvalue),
        "partners_better": int((by_partner > 0).sum()),
        "partners": len(paired.partners),
        "per_partner": _counts(by_partner),
        "top_tenth_share": _top_share(by_partner),
    }


def _headroom(paired: _Paired, known: np.ndarray, where: np.ndarray) -> dict:
    """Knowing each partner in advance (`known`) against the best static policy, on `where`."""
    diff = known[where] - paired.values[paired.best][where]
    base = paired.values[paired.best][where].mean()
    return {
        "mean": float(known[where].mean()),
        "mean_difference": float(diff.mean()),
        "stderr": _stderr(diff),
        "percent": float(100 * diff.mean() / base) if base else None,
    }


def _switching(games: list[TeamGame], adaptive: list[str]) -> dict[str, dict]:
    """Each adaptive variant's switches per game (mean, most) and games its guard fell back in."""
    switching = {}
    for a in adaptive:
        counts = [g.switches for g in games if g.agent == a]
        switching[a] = {"mean": float(np.mean(counts)), "max": int(max(counts))}
        switching[a]["guarded_games"] = int(sum(g.guarded for g in games if g.agent == a))
    return switching


def _by_subset(
    paired: _Paired, known: np.ndarray, adaptive: list[str], subsets: dict[str, Callable[[str], bool]]
) -> dict[str, dict[str, dict]]:
    """Each variant's effect on each part of the population (Holm-corrected over variants and parts)."""
    by_subset: dict[str, dict[str, dict]] = {}
    for name, chosen in subsets.items():
        where = np.array([chosen(u[0]) for u in paired.units])
        mine = np.array([chosen(p) for p in paired.partners])
        by_subset[name] = {}
        for a in adaptive:
            diff = paired.difference(a)[where]
            base = paired.values[paired.best][where].mean()
            by_subset[name][a] = paired_tests(diff) | {
                "percent": float(100 * diff.mean() / base) if base else None,
                "partners": int(mine.sum()),
                "per_partner": _counts(paired.by_partner(a)[mine]),
                "known_partner_percent": _headroom(paired, known, where)["percent"],
            }
    subset_p = holm({(n, a): t["p_superior"] for n, by in by_subset.items() for a, t in by.items()})
    for (n, a), p in subset_p.items():
        by_subset[n][a]["p_holm"] = p
    return by_subset


def compare(games: list[TeamGame], population: Population | None = None) -> Comparison:
    """Each agent's mean and standard error over the population, and each adaptive variant against
    the best static policy (chosen on this same data, which favours the static side): a one-sided
    paired t-test and a Wilcoxon signed-rank test over (partner, seed) pairs (with Holm's
    correction over the variants), the same t-test over partner means (seeds averaged), the effect
    size d_z = mean difference / sd of differences; per part of the population (its partner groups,
    or its partners' kinds), one-sided superiority and non-inferiority (margin MARGIN) tests; each
    variant's switches per game; and the headroom of knowing each partner in advance
    (`known_partner`) over the best static policy, overall and per part: what any rule that picks
    one of these static policies per partner can gain, and the share of it each variant realises.
    Per variant also how many partners it serves better, as well or worse than the best static
    policy (a partner's mean beyond MARGIN either way), and the share of its gain that the top
    tenth of partners carry. At a glance (`_glance`), each variant against fixed references (the
    best static policy, the study library's best static, the previous release's default teammate)
    with the game and the partner as the unit, the top part's share of the gain, on every partner
    and on those who can score. `population` (default: a list of these games' partners, by kind)
    names each partner's part and the subsets each variant's effect is also given for."""
    population = population or listed(sorted({g.partner for g in games}), "")
    paired = _Paired.of(games)
    adaptive, best = paired.adaptive, paired.best
    tests = {a: _test(paired, a) for a in adaptive}
    holm_p = holm({a: t["p_t"] for a, t in tests.items()})
    for a, t in tests.items():
        t["p_holm"] = holm_p[a]
    part_of = {p: population.part_of(p) for p in paired.partners}
    label = np.array([part_of[u[0]] for u in paired.units])
    parts = sorted(set(label))
    known = known_partner(paired.grid, paired.statics, paired.units)
    overall = _headroom(paired, known, np.ones(len(paired.units), dtype=bool))
    for t in tests.values():
        room = overall["mean_difference"]
        t["headroom_realised"] = t["mean_difference"] / room if room > 0 else None
    mean_of = {a: _summary(v) for a, v in paired.values.items()}
    return Comparison(
        population=population.name,
        parts=population.parts,
        units=len(paired.units),
        partners=len(paired.partners),
        part_of=part_of,
        by_subset=_by_subset(paired, known, adaptive, population.subsets),
        best_static=best,
        agents=mean_of,
        tests=tests,
        per_partner={
            p: {a: _summary([paired.grid[a][u] for u in paired.units if u[0] == p]) for a in paired.values}
            for p in paired.partners
        },
        per_part={g: {a: _summary(paired.values[a][label == g]) for a in paired.values} for g in parts},
        tests_by_part={a: {g: paired_tests(paired.difference(a)[label == g]) for g in parts} for a in tests},
        switches=_switching(games, adaptive),
        margin=MARGIN,
        known_partner={"all": overall, **{g: _headroom(paired, known, label == g) for g in parts}},
        **_glance(paired, part_of, population.role),
    )


PREVIOUS_DEFAULT = {"shooter": "GS1", "bait": "GB1"}  # our seat -> the previous release's default teammate


def _references(paired: _Paired, partner_role: str) -> tuple[dict[str, str], dict[str, str]]:
    """The fixed references these games played (label -> agent) and those they did not (label ->
    what was asked for): the best static policy (of every library compared), the study library's
    best static on these games and the previous release's default teammate of our seat (the
    partners' other seat, else the seat whose shipped static policies were played)."""
    played: dict[str, str] = {BEST: paired.best}
    shipped = (r for r in ROLES if set(held_out.statics(r)) & set(paired.statics))
    seat = other(partner_role) if partner_role else next(shipped, None)
    if seat is None:
        return played, {}
    missing: dict[str, str] = {}
    ours = library.keys(seat, library.LIBRARY)  # the study's, whatever TSF_LIBRARY adds beside it
    study = [a for a in paired.statics if a in ours]
    if study:
        played[STUDY] = max(study, key=lambda a: float(paired.values[a].mean()))
    else:
        missing[STUDY] = f"any of {', '.join(ours)}"
    previous = PREVIOUS_DEFAULT[seat]
    (played if previous in paired.statics else missing)[PREVIOUS] = previous
    return played, missing


def _family_shares(by_partner: np.ndarray, parts: list[str]) -> dict:
    """Each part's share of the total gain over partners (their mean differences summed), and the
    part with the largest: empty and None where there is no gain to share (a total of 0 or less)."""
    total = by_partner.sum()
    labels = np.array(parts)
    shares = (
        {g: float(by_partner[labels == g].sum() / total) for g in sorted(set(parts))} if total > 0 else {}
    )
    top = max(shares, key=shares.get) if shares else None
    return {"part_shares": shares, "top_part": top, "top_share": None if top is None else shares[top]}


def _unit(diff: np.ndarray, base: float) -> dict:
    """Differences with one unit (games or partners): their mean ± s.e., in % of `base` (None: not
    defined), and the one-sided paired t-test that the agent is better (team.paired_tests)."""
    t = paired_tests(diff)
    return {
        "difference": t["mean_difference"],
        "stderr": t["stderr"],
        "percent": percent(t["mean_difference"], base),
        "p": t["p_superior"],
        "n": t["n"],
    }


def _versus(paired: _Paired, agent: str, ref: str, chosen: list[str], part_of: dict[str, str]) -> dict:
    """`agent` against `ref` on the `chosen` partners, with the game and with the partner as the unit
    (the mean over partners of each partner's mean: a partner with more games weighs no more), and
    each partner part's share of the gain (partner unit)."""
    among = set(chosen)
    where = np.array([u[0] in among for u in paired.units])
    mine = np.array([p in among for p in paired.partners])
    ours, theirs = paired.partner_means(agent)[mine], paired.partner_means(ref)[mine]
    base = float(paired.values[ref][where].mean())
    return {
        "reference": base,
        "mean": float(paired.values[agent][where].mean()),
        "games": _unit(paired.values[agent][where] - paired.values[ref][where], base),
        "partners": _unit(ours - theirs, float(theirs.mean())),
        **_family_shares(ours - theirs, [part_of[p] for p in paired.partners if p in among]),
    }


def _glance(paired: _Paired, part_of: dict[str, str], partner_role: str) -> dict:
    """Comparison's figures at a glance: each adaptive variant against every fixed reference played
    (`_references`), on every partner and on the partners who can score (a static teammate at
    SCORING kills/min or more with them; the static teammates only, so that who counts does not
    depend on the agent tested)."""
    played, missing = _references(paired, partner_role)
    best_teammate = np.max([paired.partner_means(s) for s in paired.statics], axis=0)
    scoring = [p for p, kills in zip(paired.partners, best_teammate, strict=True) if kills >= SCORING]
    subsets = {"all": paired.partners, "scoring": scoring}
    glance = {
        a: {n: {label: _versus(paired, a, ref, chosen, part_of) for label, ref in played.items()}
            for n, chosen in subsets.items() if chosen}
        for a in paired.adaptive
    }  # fmt: skip
    return {"references": played, "unplayed": missing, "scoring": scoring, "glance": glance}


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
