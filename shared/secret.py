"""Comparing a secret a client sent with the one expected: in constant time, as bytes, and without
ever raising on what a client can send (not a string, non-ASCII, a lone surrogate)."""

from __future__ import annotations

import hmac


def same_secret(given: object, expected: str) -> bool:
    """Whether `given` is `expected`; anything that is not a string is not."""
    if not isinstance(given, str):
        return False
    return hmac.compare_digest(
        given.encode("utf-8", "surrogatepass"), expected.encode("utf-8", "surrogatepass")
    )


def _bytes(text: str) -> bytes:
    return text.encode("utf-8", "surrogatepass")
