"""The two ways a command ends badly, raised by the cores and turned into one line at the command
line's entry (services/commands/entry.py): never a traceback for either, unless asked for with --debug."""

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


# The optional packages, by the extra of pyproject.toml that installs them: what needs a missing one
# says which extra to install and how, never Python's bare ModuleNotFoundError.
EXTRAS = {
    "torch": "train",
    "stable_baselines3": "train",
    "sb3_contrib": "train",
    "tqdm": "train",
    "ray": "ray",
    "optuna": "search",
}


def install_line(extra: str) -> str:
    """How to install an extra: in a checkout, with the lockfile's versions, or as a package."""
    package = f"team-space-fortress[{extra}]"
    return f"pip install -c requirements.lock -e '.[{extra}]' in the checkout (or '{package}')"


def missing_extra(error: BaseException) -> str:
    """The line for an optional package that is not installed, or "" for any other error."""
    name = (getattr(error, "name", None) or "").partition(".")[0]
    if not isinstance(error, ModuleNotFoundError) or name not in EXTRAS:
        return ""
    return f"needs the `{EXTRAS[name]}` extra ({name} is not installed): {install_line(EXTRAS[name])}"
