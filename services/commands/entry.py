"""The `tsf` entry point: how a command ends is said in one line, never as a traceback.

A user's mistake (click's usage errors, shared.errors.UsageError from a core) exits 2, a failure
(shared.errors.Failure, or any other exception) exits 1. `--debug` anywhere on the command line,
or TSF_DEBUG=1, lets the traceback through instead.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Sequence

import typer

from services.agent import library
from shared import provenance
from shared.errors import Failure, UsageError, missing_extra
from shared.processes import adopt

DEBUG_HINT = "(--debug or TSF_DEBUG=1 shows the traceback)"
_interrupted: list[str] = []  # the signal that interrupted the command, if one did


def start() -> None:
    """What a `tsf` process does first. SIGINT, SIGTERM and SIGHUP interrupt a command alike, so
    that it ends through its `finally` blocks (a pool is terminated, files are closed) with one
    line and exit status 1; a command that stops gracefully installs its own (stop_on_signals). A
    process a launcher started dies with it (shared/processes.py)."""

    def interrupt(sig: int, frame: object) -> None:
        _interrupted.append(signal.Signals(sig).name)
        raise KeyboardInterrupt

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, interrupt)
    adopt()
    # Plug-ins (`my_lab.partners:Alice`) are found in the working directory, as `python -m` finds
    # them; last on the path, so a folder there never hides an installed package.
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())


def run(app: typer.Typer, args: Sequence[str] | None = None) -> int:
    """Run the app on `args` (default: the process's) and return its exit status."""
    args = list(sys.argv[1:] if args is None else args)
    debug = "--debug" in args or os.environ.get("TSF_DEBUG", "") not in ("", "0")
    args = [a for a in args if a != "--debug"]
    provenance.set_command(args)
    where = f"tsf {args[0]}" if args and not args[0].startswith("-") else "tsf"  # the command, for the line
    try:
        library.check_roots()
        status = typer.main.get_command(app).main(args or ["--help"], prog_name="tsf", standalone_mode=False)
    except typer.TyperException as error:  # click's exceptions, as typer ships them: usage errors exit 2
        context = getattr(error, "ctx", None)
        where = context.command_path if context else "tsf"
        _say(f"{where}: {' '.join(error.format_message().split())}")
        return error.exit_code
    except typer.Abort:
        _say(f"{where}: aborted")
        return 1
    except UsageError as error:
        if debug:
            raise
        _say(f"{where}: {error}")
        return 2
    except Exception as error:  # the one place where every failure becomes a line
        if debug:
            raise
        if _interrupted:  # what failed was cut short by the signal
            return _stopped(where)
        if missing_extra(error):
            _say(f"{where}: {missing_extra(error)}")
            return 1
        plain = isinstance(error, Failure | OSError)
        _say(f"{where}: {error}" if plain else f"{where}: {type(error).__name__}: {error} {DEBUG_HINT}")
        return 1
    if _interrupted:  # typer turns the KeyboardInterrupt into exit status 130, without a word
        return _stopped(where)
    return status if isinstance(status, int) else 0


def _stopped(where: str) -> int:
    _say(f"{where}: stopped by {_interrupted[0]}")
    return 1


def _say(line: str) -> None:
    print(line, file=sys.stderr)
