"""What plays a seat: a policy by key, and the check that a key can play a seat.

A key is a library policy (B1-B9, S1-S7, and those of TSF_LIBRARY: networks.py), a policy of a
library shipped beside the study's (library.NAMED: the grown library's GB1.., GS1.., the tuned
library's TB1.., TS1.. and the partner population's PB01a.., PS01a..; found by key with or without
TSF_LIBRARY, since the adaptive agent plays the tuned library's members and its groups name the
population's), a scripted one
(scripted.py), or a policy from outside the library: an SB3 `.zip`, a `module:attr` or a
`proxy:DIR` (outside.py). `policy_for` classifies a key (outside.policy_kind) and loads it;
`policy_of` loads a key already classified (a SeatSpec's kind and key).
"""

from __future__ import annotations

from pathlib import Path

from services.agent import library, outside
from services.agent.networks import load
from services.agent.scripted import scripted_keys, scripted_policy
from shared.errors import UsageError
from shared.game import ROLES, Policy


def seat_keys(role: str) -> list[str]:
    """Every key that can play `role`'s seat: the library's policies of that role, then the scripted ones."""
    return [*library.keys(role), *scripted_keys(role)]


def beside_keys(role: str) -> dict[str, Path]:
    """The policies of the libraries shipped beside the study's (library.NAMED) that play `role`'s
    seat, each with its library's directory (not listed by seat_keys, whose keys a user picks
    from: the study's library and the scripted rules). A key two of them hold is the first's: the
    third population's members share the first's keys (PB01a is the first version's, and the third
    version's where TSF_LIBRARY=population-3 puts it in use), so that a result made with one
    reproduces whatever was shipped after it."""
    found: dict[str, Path] = {}
    for root in library.NAMED.values():
        for key, recipe in library.registry(root).items():
            if recipe.role == role:
                found.setdefault(key, recipe.root)
    return found


def libraries() -> dict[str, Path]:
    """Every library whose keys load, by the name `tsf keys` gives it: the study's (`study`: B1-B9,
    S1-S7), those shipped beside it (library.NAMED: `grown`; `tuned`, the library the default agent
    plays; `population` and `population-3`, the partner populations' trained members) and the
    user's own in TSF_LIBRARY (a shipped one named there keeps its name)."""
    named = {"study": library.LIBRARY, **library.NAMED}
    shipped = {root.resolve() for root in named.values()}
    return named | {f"yours ({r})": r for r in library.roots()[1:] if r.resolve() not in shipped}


def listed_keys(role: str | None = None) -> list[tuple[str, str, str, str]]:
    """Every key that loads by itself, of `role`'s seat or both, as (key, seat, library, what): each
    library's (libraries()), then the rules (scripted.py). What `tsf keys` prints."""
    rows = [
        (key, recipe.role, name, recipe.description)
        for name, root in libraries().items()
        for key, recipe in library.registry(root).items()
        if role in (None, recipe.role)
    ]
    rules = [(key, seat, "rules", "a scripted rule") for seat in ROLES for key in scripted_keys(seat)]
    return rows + [row for row in rules if role in (None, row[1])]


def check_seat(key: str, role: str, option: str = "--policy") -> None:
    """Refuse (UsageError) a seat that is not one, or a library or scripted key that cannot play it:
    the line names the option, the value and every key that can."""
    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if key not in seat_keys(role) and key not in beside_keys(role):
        other = [r for r in ROLES if key in seat_keys(r) or key in beside_keys(r)]
        problem = f"plays the {other[0]} seat, not the {role}" if other else f"no policy of the {role} seat"
        raise UsageError(option, key, problem, seat_keys(role))


def policy_for(key: str, role: str, option: str = "--policy") -> Policy:
    """Any policy a seat can play, by key: a library policy (B1-B9, S1-S7, and those of TSF_LIBRARY),
    a scripted one, an SB3 `.zip` or a `module:attr` (outside.py); a key that cannot play the seat is
    a UsageError about `option` (check_seat)."""
    return policy_of(outside.policy_kind(key), key, role, option)


def policy_of(kind: str, key: str, role: str, option: str = "--policy") -> Policy:
    """The policy `key` names, of its `kind` (outside.policy_kind), checked to play `role`."""
    if kind != outside.BY_KEY:
        return outside.load(kind, key, role, option)
    check_seat(key, role, option)
    if key in library.registry():
        return load(key)
    if key in (beside := beside_keys(role)):
        return load(key, root=beside[key])
    return scripted_policy(key, role)
