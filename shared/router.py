"""A zenoh router in a Python session: for matches across machines, and the secured deployment.

Plain: services on several machines connect to it (`--connect tcp/<router host>:7447`).
Secured: every service logs in with a user name and password from a dictionary file, runs in
client mode (so all traffic passes the router), and the router's access control drops puts that
a user may not make: only the sim publishes the match's state, start, events and summary; each
seat's action key only from that seat's agent or human; policy switches only from the adapter or
an operator. USERS lists the names the rules know.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

import zenoh

from shared import keys
from shared.bus import BusConfig, until_stopped
from shared.errors import UsageError

USERS = (
    "sim",
    "recorder",
    "adapter",
    "operator",
    "agent-bait",
    "agent-shooter",
    "human-bait",
    "human-shooter",
)
# Who may put on which keys: every other known user is denied.
WRITERS = {
    "sim": (("sim",), ["state", "start", "event", "summary"]),
    "bait-seat": (("agent-bait", "human-bait"), ["action/bait"]),
    "shooter-seat": (("agent-shooter", "human-shooter"), ["action/shooter"]),
    "policy": (("adapter", "operator"), ["policy/*"]),
}


def access_control() -> dict:
    """The router's ACL: for each group of keys, deny puts from every known user but its writers."""
    rules, subjects, policies = [], [], []
    for name, (writers, suffixes) in WRITERS.items():
        rules.append(
            {
                "id": name,
                "messages": ["put", "delete"],
                "flows": ["ingress"],
                "permission": "deny",
                "key_exprs": [f"{keys.PREFIX}/*/{suffix}" for suffix in suffixes],
            }
        )
        subjects.append({"id": f"not-{name}", "usernames": [u for u in USERS if u not in writers]})
        policies.append({"rules": [name], "subjects": [f"not-{name}"]})
    return {
        "enabled": True,
        "default_permission": "allow",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def router_config(listen: tuple[str, ...], credentials: Path | None = None) -> zenoh.Config:
    """Router-mode config; with a credentials file (lines `user:password`), log-in and the ACL."""
    config = BusConfig("router", listen).to_zenoh()
    if credentials is not None:
        if not credentials.is_file():
            raise UsageError("--credentials", credentials, "no such file")
        auth = {"user": "router", "password": "", "dictionary_file": str(credentials.resolve())}
        config.insert_json5("transport/auth/usrpwd", json.dumps(auth))
        config.insert_json5("access_control", json.dumps(access_control()))
    return config


def run_router(listen: tuple[str, ...], credentials: Path | None, stop: threading.Event) -> None:
    """Route until `stop` is set."""
    router = zenoh.open(router_config(listen, credentials))
    logging.getLogger("tsf.router").info("routing on %s%s", listen, " (secured)" if credentials else "")
    try:
        until_stopped(stop)
    finally:
        router.close()
