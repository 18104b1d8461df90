"""numba's compiler for the project's compiled loops (the batched engine, batched rules and sampling).

numba is loaded only when something is compiled: a live agent or sim that never plays in bulk
never pays its import (half a second), which matters to an agent restarted mid-match.

Compiled code is cached in the user's cache directory (never in the checkout or the installed
package), so only the first run on a machine pays the compile time. numba checks a cached
function against its own file only, not against the `jitable` functions of other modules it calls
(engine.py's formulas, the scripted rules), so the cache lives under a digest of every source
the compiled code reads: an edit anywhere there starts a fresh cache.
"""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

_ROOT = Path(__file__).resolve().parents[2]
_SOURCES = ("services/sim", "services/agent/policy.py", "services/agent/scripted.py", "shared/game.py")
_pending: list[Callable] = []  # jitable functions declared before numba was loaded


def _digest(version: str) -> str:
    h = hashlib.blake2b(version.encode(), digest_size=8)
    for source in _SOURCES:
        path = _ROOT / source
        for file in sorted(path.glob("*.py")) if path.is_dir() else [path]:
            h.update(file.read_bytes())
    return h.hexdigest()


@functools.cache
def _numba() -> ModuleType:
    """numba, loaded once: the cache directory set and every jitable function registered."""
    import numba
    from numba.extending import register_jitable

    if not numba.config.CACHE_DIR:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
        numba.config.CACHE_DIR = str(Path(base) / "tsf" / "numba" / _digest(numba.__version__))
    for function in _pending:
        register_jitable(function)
    _pending.clear()
    return numba


def jitable(function: Callable) -> Callable:
    """A plain Python function that compiled loops may call too: Python runs it as it is (the
    scalar path keeps its exact arithmetic) and numba compiles the same source for the batch.
    Registered with numba when numba is loaded (register_jitable returns the function itself)."""
    if _numba.cache_info().currsize:
        from numba.extending import register_jitable

        register_jitable(function)
    else:
        _pending.append(function)
    return function


def njit(function: Callable) -> Callable:
    """Compile `function` in nopython mode, cached; no fastmath, so float arithmetic stays IEEE
    and in source order, as the scalar engine's. Loads numba now: for modules only bulk play uses."""
    return _numba().njit(cache=True, nogil=True)(function)


def compiled(function: Callable) -> Callable:
    """`njit`, put off until the first call: for a compiled loop that only Python calls, in a
    module that live services import too."""

    @functools.cache
    def loop() -> Callable:
        return njit(function)

    @functools.wraps(function)
    def call(*args: object) -> object:
        return loop()(*args)

    return call
