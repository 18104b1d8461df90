"""A study's config file read against the values it fills: every key one of the type's settings,
every value of the setting's kind, before any value's own checks (each type's __post_init__) run.
A mistake is a ValueError in the study's words (`crowd.bonus.max = "2"`: a number expected), never
Python's (`unexpected keyword argument`, `'<' not supported`). Pure: tables in, values out."""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from collections.abc import Callable
from typing import Any


def build(kind: Any, table: object, where: str = "") -> Any:
    """A `kind` (a dataclass, or a type with a `read` classmethod that takes the table's keys) from
    a TOML table: nested tables build their own dataclasses, lists become tuples. `where` names the
    table in messages (`crowd.`, `variants[2].`)."""
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
            raise ValueError(f"{where}{name}: missing (every {where or 'study'} needs it)")
    return make(**{name: _value(hints[name], value, f"{where}{name}") for name, value in table.items()})


def _value(hint: Any, value: object, where: str) -> Any:
    fits, words = _kind(hint)
    if not fits(value):
        raise ValueError(f"{where} = {_shown(value)}: {words} expected")
    inner = _inner(hint)
    if dataclasses.is_dataclass(inner):
        if isinstance(value, list):
            return tuple(build(inner, item, f"{where}[{i}].") for i, item in enumerate(value))
        return build(inner, value, f"{where}.")
    return tuple(value) if isinstance(value, list) else value


def _inner(hint: Any) -> Any:
    """The type a setting holds: X of `X | None` and of `tuple[X, ...]`, else the hint itself."""
    args = [a for a in typing.get_args(hint) if a is not type(None) and a is not Ellipsis]
    return _inner(args[0]) if args and typing.get_origin(hint) in (tuple, types.UnionType) else hint


def _kind(hint: Any) -> tuple[Callable[[object], bool], str]:
    """Whether a value is of a setting's kind, and the kind in words."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is types.UnionType:  # X | None: a setting left out is None; TOML has no null
        return _kind(next(a for a in args if a is not type(None)))
    if origin is tuple:
        item, words = _kind(args[0])
        return (lambda v: isinstance(v, list) and all(map(item, v))), f"a list [...] of {_plural(words)}"
    if origin is dict:
        item, words = _kind(args[1])
        return (lambda v: isinstance(v, dict) and all(map(item, v.values()))), f"a table of {_plural(words)}"
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
