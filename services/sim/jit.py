"""numba's compiler, set up once for the project's compiled loops (the batched engine).

Compiled code is cached in the user's cache directory (never in the checkout or the installed
package), so only the first run on a machine pays the compile time.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numba
from numba.extending import register_jitable

if not numba.config.CACHE_DIR:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    numba.config.CACHE_DIR = str(Path(base) / "tsf" / "numba")


def njit(function: Callable) -> Callable:
    """Compile `function` in nopython mode, cached; no fastmath, so float arithmetic stays IEEE
    and in source order, as the scalar engine's."""
    return numba.njit(cache=True, nogil=True)(function)


def jitable(function: Callable) -> Callable:
    """A plain Python function that compiled loops may call too: Python runs it as it is (the
    scalar path keeps its exact arithmetic) and numba compiles the same source for the batch."""
    return register_jitable(function)
