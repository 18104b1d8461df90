"""`tsf report`: recordings -> the original study's figures and numbers, in one directory.

DIR/report.html (self-contained), DIR/figures/*.png, DIR/data/*.csv and *.parquet (every number
behind the figures), DIR/parquet/<match>.<table>.parquet (each recording's tables, which the analyses read).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from services.agent import library
from services.report import analysis, figures
from services.report.html import Section, write_html
from services.report.load import Match, Problem, load_matches
from services.table.plot import heatmap
from services.table.table import DEFAULT_TABLE, Table
from shared.game import GameConfig
from shared.provenance import provenance

REFERENCE_GAMES = 2


@dataclass
class Report:
    html: Path
    figures: dict[str, Path] = field(default_factory=dict)
    data: dict[str, pd.DataFrame] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    matches: int = 0  # recordings in the analyses (none: the report names only problems)
    left_out: list[str] = field(default_factory=list)  # what the adaptive-vs-static tests did not compare
    provenance: dict[str, str] = field(default_factory=dict)  # what made it (shared/provenance.py)


def build_report(
    recordings: list[Path],
    out: Path,
    table_path: Path = DEFAULT_TABLE,
    partner_role: str | None = None,
    trial: str | None = None,
    reference_games: int = REFERENCE_GAMES,
    shown: Callable[[str], Callable[[int, int], None]] | None = None,
) -> Report:
    """Load, analyse, draw and write everything; a recording that cannot be used is named in the
    report and left out, and the rest still builds. `shown(step)` gives the (done, total) callback
    of each long step (the recordings replayed, the reference games)."""
    step = shown or (lambda name: lambda done, total: None)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    (out / "data").mkdir(parents=True, exist_ok=True)
    matches, problems = load_matches(recordings, out / "parquet", step("recordings replayed"))
    table = Table.load(table_path)

    partners = analysis.partner_vectors(matches, partner_role)
    for row in partners[partners["frames"] == 0].itertuples():
        problems.append(Problem(row.match, "", f"no recorded actions of the {row.partner_role} seat", True))
    partners = partners[partners["frames"] > 0].reset_index(drop=True)
    config = _common_config(matches)
    roles = sorted(set(partners["partner_role"]))
    references = _references(
        roles, table, reference_games, config, step("reference games of the library's seats")
    )
    points, variance = analysis.policy_space(partners, references)
    similarity = analysis.similarity_to_optimal(partners, table)
    correlations = analysis.correlations(similarity)
    summary = analysis.variants(partners)
    tests = analysis.adaptive_tests(partners, summary)
    left = analysis.left_out(summary, tests)
    timeline = analysis.adapter_timeline(matches)
    trial_match, seat = _trial(matches, partners, trial, partner_role)
    if trial and seat is None:
        problems.append(Problem(trial, "", "--trial: no analysed match of that name has a partner", True))
    curves = analysis.curves(trial_match, seat) if seat else pd.DataFrame()

    report = Report(
        out / "report.html", problems=problems, matches=len(matches), left_out=analysis.left_out_lines(left)
    )
    report.provenance = provenance(**library.provenance_hashes(table_path), config=config)
    report.data = {
        "table": _table_frame(table),
        "partners": partners,
        "references": pd.concat(
            [ref.rename_axis("policy").reset_index().assign(role=role) for role, ref in references.items()]
        )
        if references
        else pd.DataFrame(),
        "policy_space": points,
        "policy_space_variance": variance,
        "similarity": similarity,
        "correlations": correlations,
        "logprob_curves": curves,
        "logprob_rounds": analysis.round_means(curves),
        "variants": summary,
        "adaptive_tests": tests,
        "left_out": left,
        "adapter": timeline,
        "problems": pd.DataFrame([p.__dict__ for p in problems], columns=["name", "path", "reason", "used"]),
        "provenance": pd.DataFrame(list(report.provenance.items()), columns=["field", "value"]),
    }
    for name, frame in report.data.items():
        frame.to_csv(out / "data" / f"{name}.csv", index=False)
        frame.to_parquet(out / "data" / f"{name}.parquet", index=False)

    _draw(report, table, out / "figures", trial_match.config.fps if seat else 0)
    write_html(report.html, "Team Space Fortress: study report", _intro(report), _sections(report, seat))
    return report


def _references(
    roles: list[str], table: Table, games: int, config: GameConfig, told: Callable[[int, int], None]
) -> dict[str, pd.DataFrame]:
    """The library's seats' own behaviour vectors, by partner role (the policy space's landmarks)."""
    references = {}
    for done, role in enumerate(roles):
        told(done, len(roles))
        references[role] = analysis.reference_vectors(role, table, games, config)
    told(len(roles), len(roles))
    return references


def _table_frame(table: Table) -> pd.DataFrame:
    return pd.DataFrame(
        [
            {
                "bait": b,
                "shooter": s,
                "mean": table.mean(b, s),
                "stderr": table.stderr(b, s),
                "best_shooter": table.best_shooter(b) == s,
            }
            for b in table.baits
            for s in table.shooters
        ]
    )


def _draw(report: Report, table: Table, fig: Path, fps: int) -> None:
    """The report's figures from its data (a trial's curves where `fps`: a trial was chosen)."""
    data = report.data
    report.figures["table"] = heatmap(table, fig / "table.png")
    report.figures["policy_space"] = figures.policy_space(
        data["policy_space"], data["policy_space_variance"], fig / "policy_space.png"
    )
    report.figures["similarity"] = figures.similarity(
        data["similarity"], data["correlations"], fig / "similarity.png"
    )
    if fps:
        report.figures["logprob_curves"] = figures.curves(data["logprob_curves"], fps, fig / "logprob.png")
    report.figures["variants"] = figures.variants(
        data["variants"], data["adaptive_tests"], fig / "variants.png"
    )
    if not data["adapter"].empty:
        report.figures["adapter"] = figures.adapter(data["adapter"], fig / "adapter.png")


def _common_config(matches: list[Match]) -> GameConfig:
    """The rules most recordings were played with (the reference games use them)."""
    if not matches:
        return GameConfig()
    configs = Counter(m.config for m in matches)
    return configs.most_common(1)[0][0]


def _trial(
    matches: list[Match], partners: pd.DataFrame, trial: str | None, partner_role: str | None
) -> tuple[Match | None, analysis.Partnership | None]:
    """The match and seat whose log-probability curves are drawn: `trial` (a match name), else the
    first match with a partner."""
    for match in matches:
        if (trial in (None, match.name)) and match.name in set(partners["match"]):
            return match, analysis.seats(match, partner_role)[0]
    return None, None


def _per_round(means: pd.DataFrame) -> pd.DataFrame:
    """Round means laid out as policies x rounds, for reading."""
    wide = means.pivot(index="policy", columns="round", values="log_prob")
    return wide.rename(columns=lambda r: f"round {r}").reset_index()


def _intro(report: Report) -> str:
    text = f"{report.matches} recordings analysed."
    for p in report.problems:
        status = "used" if p.used else "left out"
        text += f"<br><span class='problem'>{p.name} ({status}): {p.reason}</span>"
    groups = report.data["variants"][analysis.GROUP].drop_duplicates()
    if len(groups) > 1:
        names = ", ".join(f"{g.kind} with {g.partner_role} partners" for g in groups.itertuples())
        text += f"<br>Compared within each group, never across them: {names}."
    for line in report.left_out:
        text += f"<br><span class='problem'>Not compared: {line}</span>"
    return text


def _sections(report: Report, seat: analysis.Partnership | None) -> list[Section]:
    d, f = report.data, report.figures
    sections = [
        Section(
            "Self-play table",
            "Mean kills per minute of every library pair (red: each bait's best shooter).",
            f["table"],
        ),
        Section(
            "Policy-space map",
            "Each partner's vector of mean log-probabilities of its actions under every library policy of "
            "its role, projected with PCA (fitted on the library's own vectors and the partners' together) "
            "to two components; library policies are the reference points, marker area grows with team "
            "performance.",
            f["policy_space"],
            [("Variance explained", d["policy_space_variance"]), ("Points", d["policy_space"])],
        ),
        Section(
            "Similarity to optimal",
            "For each partner-agent pair, the partner's similarity to the library policy of its role that "
            "the table says plays best with the agent, against team performance: Pearson r and two-sided p "
            "per role.",
            f["similarity"],
            [("Correlations", d["correlations"]), ("Pairs", d["similarity"])],
        ),
    ]
    if seat is not None:
        sections.append(
            Section(
                "Log-probability curves",
                f"Match {seat.match}, {seat.partner_role} partner {seat.partner}: each library policy's "
                "log-probability of the partner's actions (1 s moving mean), rounds shaded alternately; "
                "below, each policy's mean per round (rows: policies, columns: rounds).",
                f["logprob_curves"],
                [("Mean log-probability per round", _per_round(d["logprob_rounds"]))],
            )
        )
    sections.append(
        Section(
            "Adaptive vs static",
            "Team performance per agent variant (mean and standard error), within each group: a kind of "
            "match (study trials, a person's matches, agents only) and the partner's seat; groups are "
            "different populations and are never compared with each other. Within a group, each adaptive "
            "variant is tested against the best static variant: a paired t-test on the partners' means "
            "where every partner played both, else Welch's t-test over matches (unpaired, unequal "
            "variances); n counts partners or matches accordingly. What was not compared is listed, with "
            "the reason.",
            f["variants"],
            [("Variants", d["variants"]), ("Tests", d["adaptive_tests"]), ("Not compared", d["left_out"])],
        )
    )
    if "adapter" in f:
        sections.append(
            Section("Adapter over time", "The estimated partner type and the agent's policy.", f["adapter"])
        )
    sections.append(Section("Partners", "Every partner-agent pair and its similarity vector.", None,
                            [("Partners", d["partners"])]))  # fmt: skip
    sections.append(Section("Provenance", "What made this report (shared/provenance.py).", None,
                            [("Made by", d["provenance"])]))  # fmt: skip
    return sections
