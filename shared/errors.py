"""The two ways a command ends badly, raised by the cores and turned into one line at the command
line's entry (services/entry.py): never a traceback for either, unless asked for with --debug."""

from __future__ import annotations

from collections.abc import Iterable


class UsageError(ValueError):
    """A user's mistake: the line names the option, the value and what is accepted. Exit status 2.
    A ValueError, so that code that already handles bad values handles it too."""

    def __init__(self, option: str, value: object, problem: str, accepted: Iterable[object] = ()) -> None:
        choices = ", ".join(map(str, accepted))
        super().__init__(f"{option} {value}: {problem}" + (f"; valid: {choices}" if choices else ""))

    def __reduce__(self) -> tuple:
        """Pickled as its line (a worker process's mistake reaches the command line intact)."""
        return _usage_error, (str(self),)


def _usage_error(line: str) -> UsageError:
    error = UsageError.__new__(UsageError)
    ValueError.__init__(error, line)
    return error


class Failure(RuntimeError):
    """What was asked could not be done, for a reason outside the command line. Exit status 1."""
