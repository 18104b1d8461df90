"""The `tsf` command line: one entry point. Each area's commands live beside what they run (a
`cli.py` in its package, or beside launch.py for services and matches); this joins them."""

from __future__ import annotations

import typer

from services import matches_cli, services_cli
from services.adapter import cli as adapter_cli
from services.agent import cli as agent_cli
from services.jobs import cli as jobs_cli
from services.options import log_options
from services.proxy import cli as proxy_cli
from services.report import cli as report_cli
from services.table import cli as table_cli

app = typer.Typer(no_args_is_help=True, add_completion=False, help="Team Space Fortress.")
for group in (agent_cli, table_cli, jobs_cli, services_cli, matches_cli, adapter_cli, report_cli, proxy_cli):
    app.registered_commands += group.commands.registered_commands
    app.registered_groups += group.commands.registered_groups
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
    """The `tsf` command (services/entry.py: one line, not a traceback, when it ends badly)."""
    from services.entry import run, start

    start()
    raise SystemExit(run(app))


if __name__ == "__main__":
    main()
