"""What the `tsf` command groups share: the console, numeric options checked against their limits,
the bus options every service takes, the adaptive agent's options (built from AdapterConfig) and the
web page's host and port."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from services.adapter.core import AdapterConfig
from shared.bus import BusConfig
from shared.game import DURATION, FPS, SEEDS, Range

console = Console()

# The limits of values that only the command line sets; those of the game and the wire live in
# shared/ (game.SEEDS, FRAMES, DURATION, messages.JOB_SEEDS) and the adapter's in AdapterConfig.
GAMES = Range(1, 10_000)  # games per pair, policy or partner
WORKERS = Range(0, 256)  # processes started on this machine (0: the command's default)
SECONDS = Range(0.0, 24 * 3600.0)  # a wait: at most a day
PORTS = Range(0, 65535)


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
Duration = Annotated[float, number(..., DURATION, f"Game length in seconds ({FPS} frames each).")]


def output(default: Path | None, help: str, directory: bool = False, names: tuple[str, ...] = ()) -> Any:
    """An option naming where a command writes (a file, or with `directory` a directory made if
    missing), refused before the command starts when nothing could be written there. Defaults are
    relative to the current directory: a shipped artifact is written only when named."""

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


# Options every bus service shares. The environment can set them (space-separated endpoints), so that
# one deployment file configures every service's bus in one place (compose.yaml).
Mode = Annotated[
    str, typer.Option("--mode", envvar="TSF_MODE", help="zenoh mode: peer (default), client or router.")
]


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


def bus_options(command: Callable[..., None]) -> Callable[..., None]:
    """Give a service's command the bus options every service shares; the command receives them as
    one `bus: BusConfig` (and logging is set up, since services log)."""
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
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
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
        added = [
            inspect.Parameter(
                f.name,
                inspect.Parameter.KEYWORD_ONLY,
                default=f.default,
                annotation=Annotated[type(f.default), typer.Option(help=f.metadata["help"])],
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
