"""The `tsf` command line: one entry point. Each area's commands are a module of this package
(services/commands/, the top layer: it imports the packages it commands, none of them imports it);
this joins them, and groups them by task in `tsf --help` (PANELS), the everyday ones first."""

from __future__ import annotations

import typer

from services.commands import adapter, jobs, matches, policies, proxy, report, service, table
from services.commands.options import log_options
from shared import provenance
from shared.messages import SCHEMA_VERSION

# `tsf --help`'s panels in order, each command (and command group) by task, the everyday ones first.
PANELS = {
    "Play and watch": ["match", "play", "replay", "keys", "game"],
    "Study": ["study", "humans"],
    "Evaluate": ["eval", "calibrate-adapter", "table", "sweep", "skill-table", "skill-model", "diversity",
                 "calibrate"],
    "Train": ["train", "library", "proxy"],
    "Data": ["report", "export"],
    "Services": ["sim", "agent", "adapter", "recorder", "human", "router", "alive"],
    "Scale-out": ["worker", "workers", "match-host"],
}  # fmt: skip
PANEL = {name: panel for panel, names in PANELS.items() for name in names}
ORDER = list(PANEL)


def name_of(command: typer.models.CommandInfo) -> str:
    """A command's name as `tsf` shows it (Typer's rule for a command named after its function)."""
    return command.name or command.callback.__name__.lower().replace("_", "-")


def version_line() -> str:
    """What `tsf --version` prints: the version to cite, the checkout's commit where there is one,
    and the wire contract's schema version."""
    commit = provenance.commit()
    where = "" if commit == "unknown" else f", commit {commit[:12]}{commit[40:]}"  # the short hash, +dirty
    return f"tsf {provenance.project_version()}{where} (wire contract schema {SCHEMA_VERSION})"


def _version(asked: bool) -> None:
    if asked:
        print(version_line())
        raise typer.Exit()


app = typer.Typer(no_args_is_help=True, add_completion=False)


@app.callback()
def _main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version (and commit) and exit."
    ),
) -> None:
    """Team Space Fortress: matches, studies, evaluations and training of adaptive teammates."""


for group in (policies, table, jobs, service, matches, adapter, report, proxy):
    app.registered_commands += group.commands.registered_commands
    app.registered_groups += group.commands.registered_groups
for command in app.registered_commands:
    command.rich_help_panel = PANEL.get(name_of(command))
    # The list shows each command's first paragraph on one line: rich keeps a docstring's breaks
    command.short_help = " ".join((command.help or command.callback.__doc__ or "").split("\n\n")[0].split())
for group in app.registered_groups:
    group.rich_help_panel = PANEL.get(group.name)
app.registered_commands.sort(key=lambda c: ORDER.index(name_of(c)) if name_of(c) in PANEL else len(ORDER))
for command in [
    *app.registered_commands,
    *(c for g in app.registered_groups for c in g.typer_instance.registered_commands),
]:
    command.callback = log_options(command.callback)  # --log-level, -v, -q on every command
for group in app.registered_groups:
    group.typer_instance.registered_callback.callback = log_options(
        group.typer_instance.registered_callback.callback
    )


def main() -> None:
    """The `tsf` command (services/commands/entry.py: one line, not a traceback, when it ends badly)."""
    from services.commands.entry import run, start

    start()
    raise SystemExit(run(app))
