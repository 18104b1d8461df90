"""numba's compiler, set up once for the project's compiled loops (the batched engine).

Compiled code is cached in the user's cache directory (never in the checkout or the installed
package), so only the first run on a machine pays the compile time. numba checks a cached
function against its own file only, not against the `jitable` functions of other modules it calls
(engine.py's formulas, the scripted rules), so the cache lives under a digest of every source
the compiled code reads: an edit anywhere there starts a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import numba
from numba.extending import register_jitable

_ROOT = Path(__file__).resolve().parents[2]
_SOURCES = ("services/sim", "services/agent/policy.py", "services/agent/scripted.py", "shared/game.py")


def _digest() -> str:
    h = hashlib.blake2b(numba.__version__.encode(), digest_size=8)
    for source in _SOURCES:
        path = _ROOT / source
        for file in sorted(path.glob("*.py")) if path.is_dir() else [path]:
            h.update(file.read_bytes())
    return h.hexdigest()


if not numba.config.CACHE_DIR:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    numba.config.CACHE_DIR = str(Path(base) / "tsf" / "numba" / _digest())


def njit(function: Callable) -> Callable:
    """Compile `function` in nopython mode, cached; no fastmath, so float arithmetic stays IEEE
    and in source order, as the scalar engine's."""
    return numba.njit(cache=True, nogil=True)(function)


def jitable(function: Callable) -> Callable:
    """A plain Python function that compiled loops may call too: Python runs it as it is (the
    scalar path keeps its exact arithmetic) and numba compiles the same source for the batch."""
    return register_jitable(function)
