"""`tsf report`: the study report from recordings."""

from __future__ import annotations

from pathlib import Path

import typer

from services.options import GAMES, console, number, output
from shared.errors import Failure
from shared.game import ROLES

commands = typer.Typer()


@commands.command("report")
def report_command(
    recordings: list[Path] = typer.Argument(..., help="Recordings (.tsflog); bad ones are named, left out."),
    out: Path = output(
        Path("report"), "Directory for report.html, figures/, data/ and parquet/.", directory=True
    ),
    table: Path | None = typer.Option(None, help="The self-play table (default: the library's)."),
    partner_role: str = typer.Option(
        "", help="Only this seat is the partner in agent-agent matches (default: each seat in turn)."
    ),
    trial: str = typer.Option("", help="Match whose log-prob curves are drawn (default: the first)."),
    reference_games: int = number(2, GAMES, "Games per library policy for the reference points."),
) -> None:
    """The study's figures and numbers from recordings: one self-contained HTML report."""
    from services.report.report import build_report
    from services.table.table import DEFAULT_TABLE, StaleTable

    if partner_role not in ("", *ROLES):
        raise typer.BadParameter("bait or shooter", param_hint="--partner-role")
    try:
        report = build_report(
            recordings, out, table or DEFAULT_TABLE, partner_role or None, trial or None, reference_games
        )
    except StaleTable as error:
        console.print(f"[red]{error}[/]")
        raise typer.Exit(1) from None
    for problem in report.problems:
        colour = "yellow" if problem.used else "red"
        console.print(f"[{colour}]{problem.name}: {problem.reason}[/]")
    console.print(f"report: {report.html}  ({len(report.figures)} figures, numbers in {out / 'data'})")
    if not report.matches:
        raise Failure(f"none of the {len(recordings)} recordings is usable; {report.html} names why")
