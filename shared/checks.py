"""The one validation kit of every contract: the bus's messages (shared/messages.py) and the page's
(shared/page.py) check their fields with these, so that a name means one thing wherever it is
read (the two kits had `_text` and `_map` each, meaning different checks). Each function returns a
check: a predicate on a decoded value, True where the value is of the field's kind and range."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

Check = Callable[[Any], bool]
_NUMBERS = frozenset((float, int))


def boolean(v: Any) -> bool:
    """True or False (never 0 or 1)."""
    return isinstance(v, bool)


def whole(lo: float = -math.inf, hi: float = math.inf) -> Check:
    """An int in [lo, hi] (never a bool)."""
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi


def number(lo: float = -math.inf, hi: float = math.inf) -> Check:
    """A finite int or float in [lo, hi] (never a bool)."""
    return lambda v: (
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v <= hi
    )


def matching(pattern: str = r"[A-Za-z0-9_.:/-]{0,64}") -> Check:
    """Text that the regular expression `pattern` matches whole (ids, keys, hashes: the bus's)."""
    regex = re.compile(pattern)
    return lambda v: isinstance(v, str) and regex.fullmatch(v) is not None


def text(most: int, least: int = 0) -> Check:
    """Any text of `least` to `most` characters (what a page shows or sends)."""
    return lambda v: isinstance(v, str) and least <= len(v) <= most


def one_of(options: tuple[str, ...]) -> Check:
    return lambda v: v in options


def or_none(check: Check) -> Check:
    """None, or a value that passes `check`."""
    return lambda v: v is None or check(v)


def list_of(check: Check, most: int = 10_000) -> Check:
    """A list of at most `most` values, each passing `check`."""
    return lambda v: isinstance(v, list) and len(v) <= most and all(map(check, v))


def vector(n: int, lo: float = -1e6, hi: float = 1e6) -> Check:
    """A list of n finite numbers in [lo, hi]; C-speed builtins, since states carry hundreds."""

    def check(v: Any) -> bool:
        if not isinstance(v, list) or len(v) != n or not set(map(type, v)) <= _NUMBERS:
            return False
        try:  # NaN or an infinity anywhere makes the sum so (and a sum past the floats, overflowing,
            finite = math.isfinite(sum(v))  # is past [lo, hi] anyway); an int too big for a float raises
        except OverflowError:
            return False
        return finite and (n == 0 or (lo <= min(v) and max(v) <= hi))

    return check


def rows(width: int, most: int) -> Check:
    """At most `most` rows, each a vector of `width` numbers."""
    row = vector(width)
    return lambda v: isinstance(v, list) and len(v) <= most and all(row(r) for r in v)


def keyed(names: tuple[str, ...], value: Check) -> Check:
    """A map with exactly these `names`, each value passing `value` (one per seat, say)."""
    return lambda v: isinstance(v, dict) and set(v) == set(names) and all(value(v[k]) for k in names)


def named(value: Check) -> Check:
    """A map from any text names to values that pass `value`."""
    return lambda v: isinstance(v, dict) and all(isinstance(k, str) and value(x) for k, x in v.items())


def plain(depth: int = 4) -> Check:
    """Plain data (text, finite numbers, booleans, lists, maps with text keys), nested at most
    `depth` deep: a job's arguments and results, which its kind checks further."""

    def check(v: Any, left: int = depth) -> bool:
        if isinstance(v, (str, bool)) or v is None:
            return True
        if isinstance(v, (int, float)):
            return math.isfinite(v)
        if left == 0:
            return False
        if isinstance(v, list):
            return all(check(x, left - 1) for x in v)
        return isinstance(v, dict) and all(isinstance(k, str) and check(x, left - 1) for k, x in v.items())

    return check
