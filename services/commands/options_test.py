"""One command line: the options every command shares, enumerated options as choices, one unit for
game time, and `tsf keys`."""

import enum
import logging
import typing

import click
import pytest
import typer

from services.agent.seats import seat_keys
from services.commands.app import app
from services.commands.entry import run
from services.commands.options import setup_logging

CHOICES = ("role", "adaptive", "partner_role", "zmode", "mode", "strategy", "service")


def commands() -> dict[str, click.Command]:
    """Every `tsf` command (a group's subcommands too) by its path."""
    root = typer.main.get_command(app)
    out = {}
    for name, command in root.commands.items():
        out[name] = command
        for sub, inner in getattr(command, "commands", {}).items():
            out[f"{name} {sub}"] = inner
    return out


def choices(annotation: object) -> tuple:
    """The values an option's annotation allows (a Literal, an Enum, optionally None, or a list of
    them); empty for an open type."""
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) is typing.Literal:
        return tuple(args)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return tuple(annotation)
    return choices(args[0]) if len(args) == 1 else ()


@pytest.mark.parametrize("path", sorted(commands()))
def test_every_command_takes_the_log_options_and_its_enumerations_as_choices(path):
    command = commands()[path]
    flags = {flag for p in command.params for flag in p.opts}
    assert {"--log-level", "--verbose", "-v", "--quiet", "-q"} <= flags
    for param in command.params:
        if param.name in CHOICES:
            assert choices(param.type_descriptor.annotation), (path, param.name)
    if "--frames" in flags:  # game time: seconds, or frames as the explicit other option
        assert "--duration" in flags


def test_logging_levels_keep_other_libraries_quiet():
    try:
        setup_logging()
        assert logging.getLogger("tsf").level == logging.INFO and logging.getLogger().level == logging.WARNING
        setup_logging(quiet=True)
        assert logging.getLogger("tsf").level == logging.WARNING
        setup_logging(verbose=True)
        assert logging.getLogger("tsf").level == logging.DEBUG == logging.getLogger().level
        setup_logging("error")
        assert logging.getLogger("tsf").level == logging.ERROR
    finally:
        logging.getLogger("tsf").setLevel(logging.NOTSET)


def test_tsf_keys_lists_every_key_with_its_seat(capsys):
    assert run(app, ["keys"]) == 0
    rows = [line.split("│") for line in capsys.readouterr().out.splitlines() if line.startswith("│")]
    listed = {(cells[1].strip(), cells[2].strip()) for cells in rows if cells[1].strip()}
    for role in ("bait", "shooter"):
        assert {(key, role) for key in seat_keys(role)} <= listed
    assert run(app, ["keys", "--role", "pilot"]) == 2
