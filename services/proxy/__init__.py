"""Human proxies: policies cloned from recorded play (docs/proxies.md)."""

from __future__ import annotations

from types import ModuleType

from shared.errors import Failure, missing_extra


def trainer() -> ModuleType:
    """The training module (services/proxy/train.py), which needs torch: loaded only when something
    is trained, with one line naming the `train` extra where it is missing."""
    try:
        from services.proxy import train
    except ModuleNotFoundError as error:
        raise Failure(f"training a proxy {missing_extra(error) or error}") from None
    return train
