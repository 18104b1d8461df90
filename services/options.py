"""What the `tsf` command groups share: the console, the bus options every service takes, the
adaptive agent's options (built from AdapterConfig) and the web page's host and port."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import logging
from collections.abc import Callable
from typing import Annotated

import typer
from rich.console import Console

from services.adapter.core import AdapterConfig
from shared.bus import BusConfig

console = Console()


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


Port = Annotated[int, typer.Option(min=0, max=65535, help="Port of the web page (0: any free port).")]
