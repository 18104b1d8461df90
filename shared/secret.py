"""Secrets: comparing one a client sent with the one expected (in constant time, as bytes, and
without ever raising on what a client can send: not a string, non-ASCII, a lone surrogate), signing
a text with one, and reading one from its file."""

from __future__ import annotations

import hashlib
import hmac
from pathlib import Path

from shared.errors import UsageError

SHORTEST = 16  # characters a shared secret needs at least


def same_secret(given: object, expected: str) -> bool:
    """Whether `given` is `expected`; anything that is not a string is not."""
    if not isinstance(given, str):
        return False
    return hmac.compare_digest(_bytes(given), _bytes(expected))


def signature(secret: bytes, text: str) -> str:
    """HMAC-SHA256 of `text` (UTF-8) keyed with `secret`, in hex: what
    `printf %s TEXT | openssl dgst -sha256 -hmac SECRET` prints."""
    return hmac.new(secret, _bytes(text), hashlib.sha256).hexdigest()


def read_secret(path: Path, option: str) -> bytes:
    """The secret held in the file at `path` (surrounding white space dropped, so an editor's last
    newline does not count); a file that cannot be read or holds too short a secret is a UsageError."""
    try:
        secret = path.read_bytes().strip()
    except OSError as error:
        raise UsageError(option, path, f"cannot read the secret: {error.strerror}") from None
    if len(secret) < SHORTEST:
        raise UsageError(
            option, path, f"the secret needs at least {SHORTEST} characters, it has {len(secret)}"
        )
    return secret


def _bytes(text: str) -> bytes:
    return text.encode("utf-8", "surrogatepass")
