"""What the `tsf` command groups share: the console, numeric options checked against their limits,
the logging options every command takes, the bus options every service takes, the adaptive agent's
options (built from AdapterConfig), the choices of enumerated options, and the web page's host and
port."""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
import logging
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import EllipsisType
from typing import Annotated, Any, Literal

import typer
from rich.console import Console

from services.population.adaptive import PARTNERS, STRATEGIES, AdapterConfig
from shared import keys
from shared.bus import BusConfig
from shared.errors import UsageError
from shared.game import DURATION, FPS, FRAMES, ROLES, SEEDS, GameConfig, Range

console = Console()


@contextmanager
def progress_bars() -> Iterator[Callable[[str], Callable[[int, int], None]]]:
    """Progress on the console for a command that runs more than a few seconds: `shown(step)` adds
    a bar named `step` and gives its (done, total) callback (services/jobs/kinds.py's Progress)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=console) as bar:

        def shown(step: str) -> Callable[[int, int], None]:
            task = bar.add_task(step, total=None)
            return lambda done, total: bar.update(task, completed=done, total=total)

        yield shown


# The limits of values that only the command line sets; those of the game and the wire live in
# shared/ (game.SEEDS, FRAMES, DURATION, messages.JOB_SEEDS) and the adapter's in AdapterConfig.
GAMES = Range(1, 10_000)  # games per pair, policy or partner
WORKERS = Range(0, 256)  # processes started on this machine (0: the command's default)
SLOTS = Range(1, 1024)  # matches a match host runs at once (shared.messages.HostStatus)
SECONDS = Range(0.0, 24 * 3600.0)  # a wait: at most a day
PORTS = Range(0, 65535)
PRIORITY = Range(0, 39)  # nice steps a process may raise itself by (from 19 to -20)


def given(context: typer.Context, name: str) -> bool:
    """Whether the command's option `name` (its parameter's name) was given, on the command line or
    from the environment, rather than left at its default: an option that another makes do nothing
    is refused only when it was asked for."""
    source = context.get_parameter_source(name)
    return source is not None and source.name in ("COMMANDLINE", "ENVIRONMENT")


def refuse_beside(
    context: typer.Context, option: str, value: object, why: str, others: dict[str, str]
) -> None:
    """Refuse (UsageError) the first of `others` (parameter name -> option) given beside `option`,
    which makes it do nothing (`why`)."""
    for name, other in others.items():
        if given(context, name):
            raise UsageError(other, f"with {option} {value}", f"does nothing there ({why}): leave one out")


def free_port(host: str, port: int, option: str = "--port") -> None:
    """Refuse (UsageError) a port something else already listens on, before anything starts (a
    server that found out only when it bound the port had started its pool and written files)."""
    import errno
    import socket

    if port == 0:  # any free port
        return
    try:
        with socket.create_server((host, port)):
            pass
    except OSError as error:
        problem = (
            "in use by another program" if error.errno == errno.EADDRINUSE else error.strerror or str(error)
        )
        raise UsageError(option, port, f"{problem} on {host}: give another port") from None


def number(default: object, limits: Range, help: str) -> Any:
    """A numeric option that refuses a value outside `limits` before the command starts: one line
    naming the option, the value and the range, exit status 2 (click's usage error). Whole numbers
    when the limits are ints; NaN and infinities are outside every range. `default` is `...` inside
    Annotated."""
    kind = type(limits.low)

    def parse(text: str) -> int | float:
        try:
            value = int(text) if kind is int else float(text)
        except ValueError:
            try:
                value = float(text)  # 1e9, inf, nan, 2.5: a number, if not one of this range
            except ValueError:
                raise typer.BadParameter(f"{text} is not a number") from None
        if value not in limits:
            raise typer.BadParameter(f"{text} is outside the range {limits}")
        if kind is int and value != int(value):
            raise typer.BadParameter(f"{text} is not a whole number")
        return kind(value)

    return typer.Option(default, parser=parse, help=f"{help} [{limits}]")


Seed = Annotated[int, number(..., SEEDS, "The game's seed.")]


def output(
    default: Path | None | EllipsisType, help: str, directory: bool = False, names: tuple[str, ...] = ()
) -> Any:
    """An option naming where a command writes (a file, or with `directory` a directory made if
    missing), refused before the command starts when nothing could be written there. Defaults are
    relative to the current directory: a shipped artifact is written only when named (`...`: the
    option is required)."""

    def check(path: Path | None) -> Path | None:
        if path is None:
            return None
        if path.exists() and path.is_dir() != directory:
            raise typer.BadParameter(f"{path} is {'not ' if directory else ''}a directory")
        existing = next(p for p in (path, *path.absolute().parents) if p.exists())
        if existing != path and not existing.is_dir():
            raise typer.BadParameter(f"{path}: {existing} is not a directory")
        if not os.access(existing, os.W_OK):
            raise typer.BadParameter(f"{path}: {existing} is not writable")
        return path

    return typer.Option(default, *names, callback=check, help=help)


# The RECORDINGS argument of the commands that learn from recorded people (proxy train, humans fit).
PEOPLE_RECORDINGS = typer.Argument(
    ..., help="Recordings (.tsflog) of people; study sidecars beside them.", exists=True, dir_okay=False
)


# Enumerated options: Literal types, so that --help lists the choices and click refuses the rest.
Role = Literal[ROLES]
Strategy = Literal[STRATEGIES]
Partners = Literal[PARTNERS]
Strategies = enum.StrEnum("Strategies", [(s, s) for s in STRATEGIES])  # repeatable: typer lists take Enums
SimMode = Literal["realtime", "lockstep"]
ZenohMode = Literal["peer", "client", "router"]
LogLevel = Literal["debug", "info", "warning", "error"]
Service = Literal["sim", "agent", "recorder", "adapter", "human"]  # what `tsf alive` asks about
LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"

LOG_OPTIONS = {  # parameter name: (annotation, default)
    "log_level": (
        Annotated[
            LogLevel | None,
            typer.Option(
                "--log-level", help="The project's log level (default info; other libraries: warning)."
            ),
        ],
        None,
    ),
    "verbose": (Annotated[bool, typer.Option("--verbose", "-v", help="Log level debug.")], False),
    "quiet": (Annotated[bool, typer.Option("--quiet", "-q", help="Log level warning.")], False),
}


# Game time is in seconds everywhere (--duration); --frames gives it in frames instead.
Duration = Annotated[
    float | None, number(..., DURATION, f"Game length in seconds, default 60 ({FPS} frames each).")
]
Frames = Annotated[int | None, number(..., FRAMES, "Game length in frames, instead of --duration.")]


def game_frames(duration: float | None, frames: int | None) -> int:
    """The game's length in frames from --duration (seconds) or --frames (one of them; default 60 s)."""
    if duration is not None and frames is not None:
        raise UsageError("--frames", frames, "give the length once: --duration (seconds) or --frames")
    if frames is not None:
        return frames
    return round(duration * FPS) if duration is not None else GameConfig.frames


def keys_help(role: str | None, what: str) -> str:
    """An option's help that names the policy keys of its seat (or of both) by library, first to
    last, and points to `tsf keys`, which lists them all."""
    from services.agent.seats import listed_keys

    try:
        rows = listed_keys(role)
    except UsageError:  # a bad TSF_LIBRARY: said in one line once a command reads the library
        return f"{what} (the keys `tsf keys` lists)."
    by_library: dict[str, list[str]] = {}
    for key, _, name, _ in rows:
        by_library.setdefault(name, []).append(key)
    listed = "; ".join(
        f"{name} {keys[0]}..{keys[-1]}" if len(keys) > 3 else f"{name} {', '.join(keys)}"
        for name, keys in by_library.items()
    )
    return f"{what}: a key `tsf keys` lists ({listed}), or a .zip, module:attr or proxy:DIR."


def setup_logging(log_level: str | None = None, verbose: bool = False, quiet: bool = False) -> None:
    """The project's loggers (tsf.*) at the chosen level, every other library's at warning (debug
    opens them too): a command's own lines stay readable among zenoh's, numba's, matplotlib's."""
    if verbose and quiet:
        raise UsageError("--verbose", "--quiet", "choose one of them")
    level = log_level or ("debug" if verbose else "warning" if quiet else "info")
    root = logging.getLogger()
    root.setLevel(logging.DEBUG if level == "debug" else logging.WARNING)
    for handler in [h for h in root.handlers if isinstance(h, _Stderr)]:
        root.removeHandler(handler)  # the one an earlier command in this process set up
    handler = _Stderr()
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    root.addHandler(handler)
    logging.getLogger("tsf").setLevel(level.upper())


class _Stderr(logging.StreamHandler):
    """Writes to whatever sys.stderr is when a line comes (a redirected or captured stream too)."""

    @property
    def stream(self):  # noqa: ANN201 - a text stream
        return sys.stderr

    @stream.setter
    def stream(self, value: object) -> None:
        pass


def log_options(command: Callable[..., object]) -> Callable[..., object]:
    """Give a command --log-level, -v/--verbose and -q/--quiet, and set logging up before it runs."""
    signature = inspect.signature(command, eval_str=True)
    added = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)
        for name, (annotation, default) in LOG_OPTIONS.items()
    ]

    @functools.wraps(command)
    def with_logs(*args: object, **options: object) -> object:
        setup_logging(*(options.pop(name) for name in LOG_OPTIONS))
        return command(*args, **options)

    with_logs.__signature__ = signature.replace(parameters=[*signature.parameters.values(), *added])
    return with_logs


# Options every bus service shares. The environment can set them (space-separated endpoints), so that
# one deployment file configures every service's bus in one place (compose.yaml).
Mode = Annotated[ZenohMode, typer.Option("--mode", envvar="TSF_MODE", help="zenoh mode.")]


Listen = Annotated[
    list[str] | None,
    typer.Option("--listen", envvar="TSF_LISTEN", help="Endpoint to listen on (repeatable)."),
]


Connect = Annotated[
    list[str] | None,
    typer.Option("--connect", envvar="TSF_CONNECT", help="Endpoint to connect to (repeatable)."),
]


Multicast = Annotated[bool, typer.Option("--multicast", help="Turn multicast scouting on (off by default).")]


LowLatency = Annotated[bool, typer.Option("--low-latency", help="zenoh low-latency transport (all peers).")]


User = Annotated[
    str, typer.Option("--user", help="Log-in for a secured router; the password comes from TSF_BUS_PASSWORD.")
]


Password = Annotated[str, typer.Option("--password", envvar="TSF_BUS_PASSWORD", hidden=True)]


WaitRouter = Annotated[
    float,
    typer.Option("--wait-router", min=0.0, help="Client mode: seconds to keep trying to reach the router."),
]


Match = Annotated[
    str, typer.Option("--match", envvar="TSF_MATCH", help="Match id: the key namespace tsf/<match>/...")
]
Pool = Annotated[
    str,
    typer.Option(
        "--pool",
        help="A pool's name: play every match its orders name (tsf/pool/<pool>/order), not one --match.",
    ),
]


def in_pool(match: str, pool: str) -> bool:
    """Whether a service command plays a pool's matches (--pool) rather than one (--match); it is
    given one of the two, never both nor neither (UsageError)."""
    if match and pool:
        raise UsageError("--pool", pool, "give --pool or --match, not both")
    if not (match or pool):
        raise UsageError("--match", "(none)", "give --match (one match) or --pool (a pool's matches)")
    if match:
        keys.check_match(match)
        return False
    try:
        keys.check_name(pool)
    except UsageError:
        raise UsageError("--pool", pool, "invalid pool name: use 1-64 letters, digits, '-' or '_'") from None
    return True


BUS_OPTIONS = {  # parameter name: (annotation, default)
    "zmode": (Mode, "peer"),
    "listen": (Listen, None),
    "connect": (Connect, None),
    "multicast": (Multicast, False),
    "low_latency": (LowLatency, False),
    "user": (User, ""),
    "password": (Password, ""),
    "wait_router": (WaitRouter, 10.0),
}


# A job command's local workers (tsf eval, calibrate-adapter, library grow): one per core.
LOCAL_WORKERS = number(
    os.cpu_count() or 1, WORKERS, "Worker processes to start here (0: only workers reached with --connect)."
)

RAY = typer.Option(
    None,
    "--ray",
    metavar="ADDRESS",
    help="Run the jobs as tasks on the Ray cluster at ADDRESS (auto, HOST:PORT, ray://HOST:10001; "
    "local: a private one here) instead of on zenoh workers; needs the `ray` extra (docs/jobs.md).",
)


def bus_options(command: Callable[..., None]) -> Callable[..., None]:
    """Give a service's command the bus options every service shares; the command receives them as
    one `bus: BusConfig`."""
    own = [p for p in inspect.signature(command, eval_str=True).parameters.values() if p.name != "bus"]
    shared = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)
        for name, (annotation, default) in BUS_OPTIONS.items()
    ]

    @functools.wraps(command)
    def with_bus(**options: object) -> None:
        mode, listen, connect, multicast, low_latency, user, password, wait = (
            options.pop(n) for n in BUS_OPTIONS
        )
        listen = listen or (() if mode == "client" else ("tcp/127.0.0.1:0",))
        bus = BusConfig(
            mode, tuple(listen), tuple(connect or ()), multicast, low_latency, user, password, wait
        )
        command(bus=bus, **options)

    with_bus.__signature__ = inspect.Signature(own + shared)
    return with_bus


AdapterFactory = Callable[..., AdapterConfig]


def adapter_options(*fixed: str) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Give a command one option per AdapterConfig field, but the `fixed` ones it sets itself; the
    command receives them as `adapter(**fixed) -> AdapterConfig`, which refuses a bad value with a
    UsageError naming its option. The options are the config's fields, defaults and help, so none can
    be dropped."""
    fields = [f for f in dataclasses.fields(AdapterConfig) if f.name not in fixed]

    def decorate(command: Callable[..., None]) -> Callable[..., None]:
        own = [
            p for p in inspect.signature(command, eval_str=True).parameters.values() if p.name != "adapter"
        ]
        kinds = {"role": Role, "strategy": Strategy, "partners": Partners}  # the enumerated fields
        added = [
            inspect.Parameter(
                f.name,
                inspect.Parameter.KEYWORD_ONLY,
                default=f.metadata["default"],
                annotation=Annotated[
                    kinds.get(f.name, type(f.default)), typer.Option(help=f.metadata["help"])
                ],
            )
            for f in fields
        ]

        @functools.wraps(command)
        def with_adapter(**options: object) -> None:
            chosen = {f.name: options.pop(f.name) for f in fields}

            def adapter(**given: object) -> AdapterConfig:
                return AdapterConfig(**chosen, **given)  # a bad value: UsageError, one line (entry.py)

            command(adapter=adapter, **options)

        with_adapter.__signature__ = inspect.Signature(own + added)
        return with_adapter

    return decorate


Host = Annotated[str, typer.Option(help="Address the web page is served on (0.0.0.0: every interface).")]


Port = Annotated[int, number(..., PORTS, "Port of the web page (0: any free port).")]
