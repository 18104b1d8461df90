"""Writing an evaluation's numbers: JSON and CSV behind every figure, and a Markdown summary."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

from services.agent import library
from services.population.partners import group_of
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


def _csv(path: Path, header: list[str], rows: Iterable[Iterable]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)


def _group_table(comparison: dict) -> list[str]:
    groups = list(comparison["per_group"])
    agents = sorted(comparison["agents"], key=lambda a: (isinstance(SeatSpec.parse(a), AdaptiveSeat), a))
    rows = [
        f"| {a} | " + " | ".join(f"{comparison['per_group'][g][a]['mean']:.2f}" for g in groups) + " |"
        for a in agents
    ]
    return ["| agent | " + " | ".join(groups) + " |", "| --- |" + " --- |" * len(groups), *rows]


def _group_tests(comparison: dict) -> list[str]:
    """Each variant against the best static policy in every partner group: the difference, and the
    one-sided superiority and non-inferiority (margin) p-values."""
    by_group = comparison["tests_by_group"]
    if not by_group:
        return []
    groups = list(next(iter(by_group.values())))
    lines = [
        f"By partner group, against {comparison['best_static']}: difference ± s.e. (p superior; "
        f"p non-inferior, margin {comparison['margin']} kills/min; **bold**: non-inferior at 0.05):",
        "",
        "| adaptive | " + " | ".join(groups) + " |",
        "| --- |" + " --- |" * len(groups),
    ]
    for agent, tests in by_group.items():
        cells = []
        for g in groups:
            t = tests[g]
            difference = f"{t['mean_difference']:+.2f} ± {t['stderr']:.2f}"
            cell = f"{difference} ({t['p_superior']:.2g}; {t['p_noninferior']:.2g})"
            cells.append(f"**{cell}**" if t["noninferior"] else cell)
        lines.append(f"| {agent} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _at_a_glance(comparison: dict) -> list[str]:
    """The results first: each adaptive variant's effect against the best static policy, in %, its
    Holm-corrected p, how many partners it serves better, as well, worse, the share of the gain the
    top tenth of partners carry and the share of the known-partner headroom it realises."""
    best = comparison["best_static"]
    base = comparison["agents"][best]["mean"]

    def share(value: float | None) -> str:
        return "-" if value is None else f"{100 * value:.0f} %"

    lines = [
        f"Every partner here is simulated ({comparison['partners']} partners, "
        f"{comparison['units']} games per agent); the baseline is the best static policy, "
        f"{best} ({base:.2f} kills/min), chosen on these same games.",
        "",
        "| adaptive | effect | p (Holm) | partners better / equal / worse | top tenth's share of the gain "
        "| headroom realised |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for agent, t in comparison["tests"].items():
        counts = t.get("per_partner", {})
        lines.append(
            f"| {agent} | {100 * t['mean_difference'] / base:+.1f} % | {t.get('p_holm', float('nan')):.2g} | "
            f"{counts.get('better', '-')} / {counts.get('equal', '-')} / {counts.get('worse', '-')} | "
            f"{share(t.get('top_tenth_share'))} | {share(t.get('headroom_realised'))} |"
        )
    for name, by_agent in comparison.get("by_subset", {}).items():
        for agent, t in by_agent.items():
            c, room = t["per_partner"], t["known_partner_percent"]
            realised = t["percent"] / room if room and room > 0 else None
            lines.append(
                f"| {agent}, {name} ({t['partners']}) | {t['percent']:+.1f} % | {t['p_holm']:.2g} | "
                f"{c['better']} / {c['equal']} / {c['worse']} | - | {share(realised)} |"
            )
    return [*lines, ""]


def _known_partner(comparison: dict) -> list[str]:
    """The headroom of choosing one static policy per partner, knowing the partner in advance."""
    known = comparison.get("known_partner")
    if not known:
        return []

    def cell(h: dict) -> str:
        percent = "" if h["percent"] is None else f" ({h['percent']:+.1f} %)"
        return f"{h['mean_difference']:+.2f} ± {h['stderr']:.2f}{percent}"

    return [
        f"Knowing each partner in advance, a static policy chosen per partner (its best on the "
        f"partner's other seeds) scores {known['all']['mean']:.3f}: what any rule that picks one "
        f"of these static policies per partner can gain over {comparison['best_static']}, "
        "overall and by group (an adapter that switches within a game is not bound by it):",
        "",
        "| | " + " | ".join(known) + " |",
        "| --- |" + " --- |" * len(known),
        f"| known partner - {comparison['best_static']} | "
        + " | ".join(cell(h) for h in known.values())
        + " |",
        "",
    ]


def write_results(
    out: Path, identification_result: dict | None, games: list[TeamGame], comparison: dict | None
) -> Path:
    """Every number behind the figures, as JSON and CSV, and a Markdown summary (summary.md)."""
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Adapter evaluation", "", *(_at_a_glance(comparison) if comparison else [])]
    if identification_result:
        (out / "identification.json").write_text(json.dumps(identification_result, indent=1) + "\n")
        keys = identification_result["partners"]
        held_out = identification_result.get("held_out")
        lines += [
            "## Identification ("
            + ("the test members' partner groups" if held_out else "library partners")
            + ", 10 % action noise)",
            "",
            "| T | CEM accuracy | filter accuracy | CEM follows within T/2 | median frames to follow |",
            "| --- | --- | --- | --- | --- |",
        ]
        for window, r in identification_result["windows"].items():
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
        lines.append("")
    if games:
        _csv(out / "team.csv", list(games[0].row()), (g.row().values() for g in games))
    if comparison:
        (out / "comparison.json").write_text(json.dumps(comparison, indent=1) + "\n")
        agents = comparison["agents"]
        _csv(
            out / "per_partner.csv",
            ["partner", "group", "agent", "kills_per_minute", "stderr", "games"],
            (
                [
                    p,
                    comparison.get("group_of", {}).get(p) or group_of(p),
                    a,
                    f"{v['mean']:.4f}",
                    f"{v['stderr']:.4f}",
                    v["n"],
                ]
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
            *_known_partner(comparison),
            "| adaptive | difference | d_z | p (paired t) | p (Holm) | p (Wilcoxon) | p (partners) | "
            "partners better | switches/game (max) | guard fell back |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
            *(
                f"| {a} | {t['mean_difference']:+.3f} ± {t['stderr']:.3f} | {t['d_z']:+.3f} | "
                f"{t['p_t']:.3g} | {t.get('p_holm', float('nan')):.3g} | {t['p_wilcoxon']:.3g} | "
                f"{t['p_t_partners']:.3g} | {t['partners_better']}/{t['partners']} | "
                f"{comparison['switches'][a]['mean']:.1f} ({comparison['switches'][a]['max']}) | "
                f"{comparison['switches'][a]['guarded_games']} games |"
                for a, t in comparison["tests"].items()
            ),
            "",
            *_group_tests(comparison),
        ]
    made = provenance(**library.provenance_hashes())
    (out / "provenance.json").write_text(json.dumps(made, indent=1) + "\n")
    lines += ["## Provenance", "", *(f"- {line}" for line in provenance_lines(made)), ""]
    path = out / "summary.md"
    path.write_text("\n".join(lines))
    return path
