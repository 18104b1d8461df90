"""Writing an evaluation's numbers: JSON and CSV behind every figure, and a Markdown summary."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from services.agent import library
from services.population.adaptive import SHIPPED
from services.population.seat import AdaptiveSeat, SeatSpec
from shared.errors import UsageError
from shared.provenance import lines as provenance_lines
from shared.provenance import provenance


@dataclass(frozen=True)
class TeamGame:
    """One team game: a row of team.csv."""

    partner: str
    agent: str
    seed: int
    kills_per_minute: float
    switches: int
    guarded: int  # 1 where a -guard strategy fell back to the best static policy
    trial: int | None = None  # the trial, in games played as sessions

    def row(self) -> dict:
        """The game as team.csv writes it: the trial only for sessions."""
        row = asdict(self)
        return row if self.trial is not None else {k: v for k, v in row.items() if k != "trial"}


NOT_DEFINED = "not defined"  # a ratio whose base is zero (the best static policy scores 0)


def percent(part: float, base: float) -> float | None:
    """`part` in per cent of `base`; None ("not defined") where the base is zero."""
    return 100 * part / base if base else None


def percent_text(value: float | None, digits: int = 1) -> str:
    """A per cent as the summary writes it, or that it is not defined."""
    return NOT_DEFINED if value is None else f"{value:+.{digits}f} %"


# The fixed references every adaptive variant is compared with (Comparison.references' labels).
BEST = "best static"  # the best static policy of every library compared, chosen on these games
STUDY = "study's best static"  # the study library's best static policy (S1-S7 / B1-B9) on these games
PREVIOUS = "previous default"  # the previous release's default teammate of our seat (GS1 / GB1)
SCORING = 1.0  # kills/min: a partner who can score has a static teammate this good or better


@dataclass(frozen=True)
class Comparison:
    """What `team.compare` measured (comparison.json): every agent's mean, each adaptive variant
    against the best static policy (`tests`), broken down by the population's parts (`parts`:
    its partner groups, G1.., or its partners' kinds) and subsets, and the headroom of knowing
    each partner in advance. Written by `to_json`, read back by `of`."""

    population: str  # the population's name (populations.py)
    parts: str  # what `part_of` names: "group" (partner groups) or "kind"
    units: int  # (partner, seed) games per agent
    partners: int
    part_of: dict[str, str]  # partner -> its part
    by_subset: dict[str, dict[str, dict]]  # subset -> variant -> its tests there
    best_static: str
    agents: dict[str, dict]  # agent -> mean, stderr, n
    tests: dict[str, dict]  # variant -> its tests against the best static policy
    per_partner: dict[str, dict[str, dict]]  # partner -> agent -> mean, stderr, n
    per_part: dict[str, dict[str, dict]]  # part -> agent -> mean, stderr, n
    tests_by_part: dict[str, dict[str, dict]]  # variant -> part -> superiority, non-inferiority
    switches: dict[str, dict]  # variant -> switches per game, most, games its guard fell back in
    margin: float  # kills/min: the non-inferiority margin
    known_partner: dict[str, dict]  # "all" and each part -> the known-partner headroom
    references: dict[str, str]  # label (BEST, STUDY, PREVIOUS) -> the agent played as that reference
    unplayed: dict[str, str]  # label -> the reference these games did not play (what was asked for)
    scoring: list[str]  # the partners who can score: a static teammate at SCORING kills/min or more
    # variant -> "all" or "scoring" (partners) -> reference label -> the variant against it, with the
    # game and the partner as the unit, and each part's share of the gain (team._versus)
    glance: dict[str, dict[str, dict[str, dict]]]

    @property
    def base(self) -> float:
        """The best static policy's mean kills/min: the base of every effect in per cent."""
        return self.agents[self.best_static]["mean"]

    def effect(self, agent: str) -> float | None:
        """A variant's effect in per cent of the best static policy (None: not defined)."""
        return percent(self.tests[agent]["mean_difference"], self.base)

    @property
    def scoreless(self) -> list[str]:
        """The partners with whom no agent scores: a result of its own, said as such."""
        return [p for p, by in self.per_partner.items() if all(v["mean"] == 0 for v in by.values())]

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def of(cls, data: dict) -> Comparison:
        """A comparison.json read back: one written before parts were named reads as groups, and a
        part an older one lacks (its population, each partner's part, its subsets, the figures at a
        glance) as empty."""
        renamed = {"group_of": "part_of", "per_group": "per_part", "tests_by_group": "tests_by_part"}
        older = {"population": "", "parts": "group", "part_of": {}, "by_subset": {}, "known_partner": {}}
        older |= {"references": {}, "unplayed": {}, "scoring": [], "glance": {}}
        data = older | {renamed.get(k, k): v for k, v in data.items()}
        return cls(**{f.name: data[f.name] for f in fields(cls)})


def read_games(path: Path) -> list[TeamGame]:
    """The games of a team.csv, as `write_results` wrote them (for an analysis made again without
    playing); a file that is not one is a UsageError naming the file and what it lacks."""
    fields = ["partner", "agent", "seed", "kills_per_minute", "switches", "guarded"]
    wrong = UsageError("--games", path, "not an evaluation's team.csv", fields)
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            if not set(fields) <= set(reader.fieldnames or ()):
                raise wrong
            games = [
                TeamGame(r["partner"], r["agent"], int(r["seed"]), float(r["kills_per_minute"]),
                         int(r["switches"]), int(r["guarded"]), int(r["trial"]) if r.get("trial") else None)
                for r in reader
            ]  # fmt: skip
    except OSError as e:
        raise UsageError("--games", path, f"cannot be read ({e.strerror})") from None
    except (ValueError, TypeError, csv.Error):  # not text, not CSV, or a row that is not a game
        raise wrong from None
    if not games:
        raise UsageError("--games", path, "has no games")
    return games


def population_of(path: Path) -> str:
    """The population a team.csv's games were played with ("" for one written before it was
    recorded, or for no games)."""
    with path.open(newline="") as f:
        first = next(csv.DictReader(f), None) or {}
    return first.get("population") or ""


def _csv(path: Path, header: list[str], rows: Iterable[Iterable]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)


def _part_table(c: Comparison) -> list[str]:
    parts = list(c.per_part)
    agents = sorted(c.agents, key=lambda a: (isinstance(SeatSpec.parse(a), AdaptiveSeat), a))
    rows = [f"| {a} | " + " | ".join(f"{c.per_part[g][a]['mean']:.2f}" for g in parts) + " |" for a in agents]
    return ["| agent | " + " | ".join(parts) + " |", "| --- |" + " --- |" * len(parts), *rows]


def _part_tests(c: Comparison) -> list[str]:
    """Each variant against the best static policy in every part of the population: the
    difference, and the one-sided superiority and non-inferiority (margin) p-values."""
    if not c.tests_by_part:
        return []
    parts = list(next(iter(c.tests_by_part.values())))
    lines = [
        f"By partner {c.parts}, against {c.best_static}: difference ± s.e. (p superior; "
        f"p non-inferior, margin {c.margin} kills/min; **bold**: non-inferior at 0.05):",
        "",
        "| adaptive | " + " | ".join(parts) + " |",
        "| --- |" + " --- |" * len(parts),
    ]
    for agent, tests in c.tests_by_part.items():
        cells = []
        for g in parts:
            t = tests[g]
            difference = f"{t['mean_difference']:+.2f} ± {t['stderr']:.2f}"
            cell = f"{difference} ({t['p_superior']:.2g}; {t['p_noninferior']:.2g})"
            cells.append(f"**{cell}**" if t["noninferior"] else cell)
        lines.append(f"| {agent} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _share(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def _at_a_glance(c: Comparison) -> list[str]:
    """The results first: each adaptive variant's effect against the best static policy, in %, its
    Holm-corrected p, how many partners it serves better, as well, worse, the share of the gain the
    top tenth of partners carry and the share of the known-partner headroom it realises. Partners
    with whom nobody scores are said as such; an effect in % of a best static mean of 0 is not
    defined, and said so."""
    lines = [
        f"Every partner here is simulated ({c.partners} partners of the population "
        f"{c.population or '(unnamed)'}, {c.units} games per agent); the baseline is the best static "
        f"policy, {c.best_static} ({c.base:.2f} kills/min), chosen on these same games.",
        "",
    ]
    if c.scoreless:
        lines += [
            f"No agent scores with {len(c.scoreless)} of the {c.partners} partners (0 kills/min with "
            f"every agent): {', '.join(c.scoreless)}.",
            "",
        ]
    if not c.base:
        lines += [f"The best static policy scores 0, so each effect in % is {NOT_DEFINED}.", ""]
    lines += [
        "| adaptive | effect | p (Holm) | partners better / equal / worse | top tenth's share of the gain "
        "| headroom realised |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for agent, t in c.tests.items():
        n = t.get("per_partner", {})
        lines.append(
            f"| {_named(agent)} | {percent_text(c.effect(agent))} | {t.get('p_holm', float('nan')):.2g} | "
            f"{n.get('better', '-')} / {n.get('equal', '-')} / {n.get('worse', '-')} | "
            f"{_share(t.get('top_tenth_share'))} | {_share(t.get('headroom_realised'))} |"
        )
    for name, by_agent in c.by_subset.items():
        for agent, t in by_agent.items():
            n, room, effect = t["per_partner"], t["known_partner_percent"], t["percent"]
            realised = effect / room if room and room > 0 and effect is not None else None
            lines.append(
                f"| {agent}, {name} ({t['partners']}) | {percent_text(effect)} | {t['p_holm']:.2g} | "
                f"{n['better']} / {n['equal']} / {n['worse']} | - | {_share(realised)} |"
            )
    return [*lines, ""]


def _named(agent: str) -> str:
    """An agent as the summary names it: the shipped default (adaptive.SHIPPED) marked as such."""
    return f"{agent} (default)" if agent == SHIPPED.name else agent


def _versus_row(agent: str, subset: str, against: str, v: dict) -> str:
    """One row of `_against_references`: the agent against one reference on one set of partners."""

    def cell(unit: dict) -> str:
        return f"{unit['difference']:+.3f} ± {unit['stderr']:.3f} ({percent_text(unit['percent'])})"

    top = NOT_DEFINED if v["top_part"] is None else f"{v['top_part']}: {100 * v['top_share']:.0f} %"
    return (
        f"| {_named(agent)} | {subset} | {against} | {v['mean']:.3f} / {v['reference']:.3f} | "
        f"{cell(v['games'])} | {cell(v['partners'])} | {v['games']['p']:.2g} / {v['partners']['p']:.2g} | "
        f"{top} |"
    )


def _against_references(c: Comparison) -> list[str]:
    """Each adaptive agent, the shipped default first, against every fixed reference played (the
    best static policy, the study library's best static, the previous release's default teammate;
    one row where they are one agent), on every partner and on those who can score; a reference
    not played is said to be."""
    if not c.glance:
        return []
    refs: dict[str, list[str]] = {}
    for label, agent in c.references.items():
        refs.setdefault(agent, []).append(label)
    lines = [
        "## Against fixed references",
        "",
        "Each adaptive agent against each reference these games played ("
        + "; ".join(f"{' and '.join(labels)}: {agent}" for agent, labels in refs.items())
        + "): kills/min, the difference in kills/min and % with the game as the unit (every partner "
        "and seed) and with the partner as the unit (the mean over partners of each partner's mean), "
        "one-sided paired t-tests over games / over partners, and the share of the gain (partner "
        f"unit) from the top partner {c.parts}. On every partner, and on the partners who can score "
        f"(a static teammate at {SCORING:g} kill/min or more: {len(c.scoring)} of {c.partners}).",
        "",
        *(
            f"Not played in these games: the {label} ({asked}), so no comparison with it."
            for label, asked in c.unplayed.items()
        ),
        *([""] if c.unplayed else []),
        f"| adaptive | partners | against | kills/min (agent / reference) | difference, games | "
        f"difference, partners | p, games / partners | top {c.parts}'s share of the gain |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    names = {"all": f"all ({c.partners})", "scoring": f"can score ({len(c.scoring)})"}
    for agent in sorted(c.glance, key=lambda a: a != SHIPPED.name):
        for subset, by_label in c.glance[agent].items():
            for ref, labels in refs.items():
                against = f"{ref} ({', '.join(labels)})"
                lines.append(_versus_row(agent, names[subset], against, by_label[labels[0]]))
    if not c.scoring:
        lines += [
            "",
            f"No partner can score here (no static teammate reaches {SCORING:g} kill/min with any).",
        ]
    return [*lines, ""]


def _known_partner(c: Comparison) -> list[str]:
    """The headroom of choosing one static policy per partner, knowing the partner in advance."""
    known = c.known_partner
    if not known:
        return []

    def cell(h: dict) -> str:
        in_percent = "" if h["percent"] is None else f" ({h['percent']:+.1f} %)"
        return f"{h['mean_difference']:+.2f} ± {h['stderr']:.2f}{in_percent}"

    return [
        f"Knowing each partner in advance, a static policy chosen per partner (its best on the "
        f"partner's other seeds) scores {known['all']['mean']:.3f}: what any rule that picks one "
        f"of these static policies per partner can gain over {c.best_static}, "
        f"overall and by {c.parts} (an adapter that switches within a game is not bound by it):",
        "",
        "| | " + " | ".join(known) + " |",
        "| --- |" + " --- |" * len(known),
        f"| known partner - {c.best_static} | " + " | ".join(cell(h) for h in known.values()) + " |",
        "",
    ]


def _identification(out: Path, found: dict) -> list[str]:
    """identification.json and the confusion matrices into `out`; the summary's section."""
    (out / "identification.json").write_text(json.dumps(found, indent=1) + "\n")
    keys = found["partners"]
    lines = [
        "## Identification ("
        + ("the test members' partner groups" if found.get("held_out") else "library partners")
        + ", 10 % action noise)",
        "",
        "| T | CEM accuracy | filter accuracy | CEM follows within T/2 | median frames to follow |",
        "| --- | --- | --- | --- | --- |",
    ]
    for window, r in found["windows"].items():
        confusion = ([k, *row] for k, row in zip(keys, r["confusion"], strict=True))
        _csv(out / f"confusion_T{window}.csv", ["true \\ estimated", *keys], confusion)
        follow = r["follow"]
        followed = (
            f"{follow['within_half_window']:.2f} ({follow['followed']}/{follow['switches']} followed)"
            if follow["switches"]
            else "- (no switching partners)"
        )
        lines.append(
            f"| {window} | {r['accuracy']:.3f} | {r['bayes_accuracy']:.3f} | {followed} | "
            f"{follow['median_frames'] if follow['switches'] else '-'} |"
        )
    return [*lines, ""]


def _team(out: Path, c: Comparison) -> list[str]:
    """comparison.json and per_partner.csv into `out`; the summary's team performance section."""
    (out / "comparison.json").write_text(json.dumps(c.to_json(), indent=1) + "\n")
    _csv(
        out / "per_partner.csv",
        ["partner", c.parts, "agent", "kills_per_minute", "stderr", "games", "population"],
        (
            [p, c.part_of[p], a, f"{v['mean']:.4f}", f"{v['stderr']:.4f}", v["n"], c.population]
            for p, by_agent in c.per_partner.items()
            for a, v in by_agent.items()
        ),
    )
    return [
        f"## Team performance ({c.partners} partners, {c.units} games per agent)",
        "",
        "| agent | kills/min | s.e. |",
        "| --- | --- | --- |",
        *(f"| {a} | {v['mean']:.3f} | {v['stderr']:.3f} |" for a, v in sorted(c.agents.items())),
        "",
        f"Mean kills/min by partner {c.parts} (every partner: per_partner.csv):",
        "",
        *_part_table(c),
        "",
        f"Best static policy: **{c.best_static}**.",
        "",
        *_known_partner(c),
        "| adaptive | difference | d_z | p (paired t) | p (Holm) | p (Wilcoxon) | p (partners) | "
        "partners better | switches/game (max) | guard fell back |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        *(
            f"| {a} | {t['mean_difference']:+.3f} ± {t['stderr']:.3f} | {t['d_z']:+.3f} | "
            f"{t['p_t']:.3g} | {t.get('p_holm', float('nan')):.3g} | {t['p_wilcoxon']:.3g} | "
            f"{t['p_t_partners']:.3g} | {t['partners_better']}/{t['partners']} | "
            f"{c.switches[a]['mean']:.1f} ({c.switches[a]['max']}) | {c.switches[a]['guarded_games']} games |"
            for a, t in c.tests.items()
        ),
        "",
        *_part_tests(c),
    ]


def write_results(
    out: Path,
    identification_result: dict | None,
    games: list[TeamGame],
    comparison: Comparison | None,
    population: str = "",
) -> Path:
    """Every number behind the figures, as JSON and CSV (each naming the `population`), and a
    Markdown summary (summary.md)."""
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Adapter evaluation", "", f"Population: {population or '(unnamed)'}.", ""]
    lines += [*_at_a_glance(comparison), *_against_references(comparison)] if comparison else []
    if identification_result:
        lines += _identification(out, identification_result | {"population": population})
    if games:
        rows = [g.row() | {"population": population} for g in games]
        _csv(out / "team.csv", list(rows[0]), (r.values() for r in rows))
    if comparison:
        lines += _team(out, comparison)
    made = provenance(**library.provenance_hashes())
    (out / "provenance.json").write_text(json.dumps(made | {"population": population}, indent=1) + "\n")
    lines += ["## Provenance", "", *(f"- {line}" for line in provenance_lines(made)), ""]
    path = out / "summary.md"
    path.write_text("\n".join(lines))
    return path
