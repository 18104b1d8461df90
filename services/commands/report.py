"""`tsf report` and `tsf export`: recordings as the study report, and as tidy Parquet tables."""

from __future__ import annotations

from pathlib import Path

import typer

from services.commands.options import GAMES, Role, console, number, output, progress_bars
from shared.errors import Failure, UsageError

commands = typer.Typer()


@commands.command("report")
def report_command(
    recordings: list[Path] = typer.Argument(..., help="Recordings (.tsflog); bad ones are named, left out."),
    out: Path = output(
        Path("report"), "Directory for report.html, figures/, data/ and parquet/.", directory=True
    ),
    table: Path | None = typer.Option(None, help="The self-play table (default: the library's)."),
    partner_role: Role | None = typer.Option(
        None, help="Only this seat is the partner in agent-agent matches (default: each seat in turn)."
    ),
    trial: str = typer.Option("", help="Match whose log-prob curves are drawn (default: the first)."),
    reference_games: int = number(2, GAMES, "Games per library policy for the reference points."),
) -> None:
    """The study's figures and numbers from recordings: one self-contained HTML report."""
    from services.report.report import build_report
    from services.table.table import DEFAULT_TABLE, StaleTable
    from shared import provenance

    try:
        with progress_bars() as shown:
            report = build_report(
                recordings, out, table or DEFAULT_TABLE, partner_role, trial or None, reference_games, shown
            )
    except StaleTable as error:
        console.print(f"[red]{error}[/]")
        raise typer.Exit(1) from None
    for problem in report.problems:
        colour = "yellow" if problem.used else "red"
        console.print(f"[{colour}]{problem.name}: {problem.reason}[/]")
    for line in report.left_out:
        console.print(f"[yellow]not compared: {line}[/]", highlight=False)
    console.print(f"report: {report.html}  ({len(report.figures)} figures, numbers in {out / 'data'})")
    console.print("\n".join(provenance.lines(report.provenance)), highlight=False)
    if not report.matches:
        raise Failure(f"none of the {len(recordings)} recordings is usable; {report.html} names why")


@commands.command("export")
def export_command(
    recordings: list[Path] = typer.Argument(..., exists=True, dir_okay=False, help="Recordings (.tsflog)."),
    out: Path = output(..., "Directory for the tables: <match>.<table>.parquet.", directory=True),
    allow_damaged: bool = typer.Option(
        False, "--allow-damaged", help="Export a damaged or incomplete recording too (its gaps are a table)."
    ),
) -> None:
    """Export recordings as tidy Parquet tables, one file per table and match (docs/recording.md)."""
    from services.recorder.export import export, name_of
    from services.recorder.recording import load

    loaded = []
    for path in recordings:
        try:
            recording = load(path)
        except ValueError as error:
            raise Failure(f"{path}: {error}") from None
        if recording.problems() and not allow_damaged:
            raise Failure(f"{path}: {'; '.join(recording.problems())} (--allow-damaged exports it anyway)")
        loaded.append(recording)
    names = [name_of(r) for r in loaded]
    if len(set(names)) < len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise UsageError("RECORDINGS", ", ".join(twice), "more than one recording of this match")
    for recording, name in zip(loaded, names, strict=True):
        export(recording, out, name)
        console.print(f"{recording.path}: {out}/{name}.*.parquet")
