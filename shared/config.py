"""A config file read whole against the values it fills, the one reader of every file a user may
write or edit (a study's config, a population spec, a library's registry, partner groups, the
adapter's calibration): every key one of the type's settings at every depth, every value of the
setting's kind, then each value's own checks (each type's __post_init__: ranges, what must not be
empty). A mistake is a ValueError in the file's words (`crowd.bonus.max = "2"`: a number expected),
never Python's (`unexpected keyword argument`, `'<' not supported`), and `read` turns it into one
line that names the option, the file and the key path, before anything starts."""

from __future__ import annotations

import dataclasses
import inspect
import json
import tomllib
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from shared.errors import UsageError


def read(kind: Any, path: str | Path, option: str) -> Any:
    """A `kind` built from the TOML or JSON file at `path` (by its suffix), checked whole; a
    UsageError naming `option`, the file, the key path and what is accepted where it is wrong."""
    table = load(path, option)
    try:
        return build(kind, table)
    except ValueError as error:
        raise UsageError(option, path, str(error)) from None


def load(path: str | Path, option: str) -> dict:
    """The tables of the TOML or JSON file at `path`, unchecked; a UsageError if it cannot be read."""
    path = Path(path)
    kind = "JSON" if path.suffix == ".json" else "TOML"
    try:
        text = path.read_text()
        table = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except FileNotFoundError:
        raise UsageError(option, path, "no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as error:  # JSON's and TOML's syntax errors too
        raise UsageError(option, path, f"cannot be read as {kind} ({error})") from None
    if not isinstance(table, dict):
        raise UsageError(option, path, f"cannot be read as {kind} (a table expected at its top)")
    return table


def build(kind: Any, table: object, where: str = "") -> Any:
    """A `kind` (a dataclass, or a type with a `read` classmethod that takes the table's keys) from
    a TOML or JSON file's table: nested tables build their own dataclasses, lists become tuples.
    `where` names the table in messages (`crowd.`, `variants[2].`)."""
    make = getattr(kind, "read", kind)
    if not isinstance(table, dict):
        raise ValueError(f"{where.rstrip('.') or 'the file'}: a table expected, got {table!r}")
    hints = typing.get_type_hints(make)
    params = {n: p for n, p in inspect.signature(make).parameters.items() if n not in ("self", "cls")}
    for name in table:
        if name not in params:
            raise ValueError(f"{where}{name}: no such setting; valid: {', '.join(params)}")
    for name, param in params.items():
        if name not in table and param.default is inspect.Parameter.empty:
            raise ValueError(f"{where}{name}: missing (a required setting)")
    values = {name: _value(hints[name], value, f"{where}{name}") for name, value in table.items()}
    try:
        return make(**values)
    except ValueError as error:  # the value's own checks, said of the table they are in
        raise ValueError(_said_of(where.rstrip("."), str(error))) from None


def _said_of(table: str, problem: str) -> str:
    """A check's line prefixed by its table's path, unless it already names the table."""
    named = table.rsplit(".", 1)[-1].split("[")[0]
    return f"{table}: {problem}" if table and not problem.startswith((table, named)) else problem


def _value(hint: Any, value: object, where: str) -> Any:
    fits, words = _kind(hint)
    if not fits(value):
        raise ValueError(f"{where} = {_shown(value)}: {words} expected")
    return _made(hint, value, where)


def _made(hint: Any, value: Any, where: str) -> Any:
    """A value of a setting's kind as the setting holds it: lists as tuples, tables of a dataclass
    built, at any depth (`seats.bait.groups[0].`)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is types.UnionType:
        return _made(next(a for a in args if a is not type(None)), value, where)
    if origin is tuple:
        return tuple(_value(args[0], item, f"{where}[{i}]") for i, item in enumerate(value))
    if origin is dict:
        return {key: _value(args[1], item, f"{where}.{key}") for key, item in value.items()}
    if dataclasses.is_dataclass(hint):
        return build(hint, value, f"{where}.")
    return value


def _kind(hint: Any) -> tuple[Callable[[object], bool], str]:
    """Whether a value is of a setting's kind, and the kind in words."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is types.UnionType:  # X | None: a setting left out is None; TOML has no null
        return _kind(next(a for a in args if a is not type(None)))
    if origin is tuple:
        words = _kind(args[0])[1]  # the items are checked one by one, each named by its place
        return (lambda v: isinstance(v, list)), f"a list [...] of {_plural(words)}"
    if origin is dict:
        words = _kind(args[1])[1]
        return (lambda v: isinstance(v, dict)), f"a table of {_plural(words)}"
    if dataclasses.is_dataclass(hint):
        return (lambda v: isinstance(v, dict)), "a table"
    if hint is str:
        return (lambda v: isinstance(v, str)), "text in quotes"
    if hint is bool:
        return (lambda v: isinstance(v, bool)), "true or false"
    if hint is int:
        return (lambda v: isinstance(v, int) and not isinstance(v, bool)), "a whole number"
    if hint is float:
        return (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)), "a number"
    raise TypeError(f"no config kind for {hint!r}")  # a setting of a type this reader does not know


def _plural(words: str) -> str:
    plural = {"text in quotes": "texts in quotes", "a whole number": "whole numbers", "a number": "numbers"}
    return plural.get(words, words.removeprefix("a ") + "s")


def _shown(value: object) -> str:
    if isinstance(value, (str, bool)):  # as TOML writes them
        text = f'"{value}"' if isinstance(value, str) else str(value).lower()
    else:
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
