"""How the study server serves (`Serving`): its capacity, limits, match hosts, secrets and
dashboard; none of it is part of the protocol, so changing it keeps the journal."""

from __future__ import annotations

import ssl
from dataclasses import dataclass
from pathlib import Path

from services.human.gateway import Web
from shared.bus import BusConfig
from shared.errors import UsageError


@dataclass(frozen=True)
class Serving:
    """How the server runs the study (not part of the protocol: changing it keeps the journal)."""

    max_matches: int = 4  # matches at once; more trials wait in a queue
    trial_timeout: float = 120.0  # seconds a match may take beyond its length, start-up included
    low_latency: bool = True  # zenoh's low-latency transport within each match
    test_token: str = ""  # a hello with this `test` token may ask for the observation values (stand-ins)
    arrivals: float = 1.0  # new participant ids a second, on average (bursts of ARRIVAL_BURST)
    # ... and from one address (bursts of ADDRESS_BURST; 0: none), so that one client cannot drain
    # the ids of all; behind a reverse proxy, the address it forwards (Web.trusted)
    arrivals_per_address: float = 0.1
    # Reconnects (a reload resumes, and cuts the trial being played) of one participant a second, by
    # any way back in: their id and key, a signed link, the platform's link (bursts of RECONNECT_BURST;
    # 0: none, a participant who leaves cannot come back). Refusals of one address: admission.REFUSALS
    reconnects: float = 0.1
    # Seconds the running matches' frames may reach the server late (Lag, the worst of the last 5 s)
    # before no new match starts on this machine until they catch up (0: no hold)
    max_lag: float = 0.025
    ready_timeout: float = 120.0  # seconds an offered trial waits for Ready; then its match and slot go
    hosts: BusConfig | None = None  # the router where match hosts offer their slots; None: local only
    # A signed link's secret: new participants need a worker id and its signature (`sig`, the
    # HMAC-SHA256 of the id with this secret, shared.secret.signature); b"": links are not signed.
    link_secret: bytes = b""
    host_secret: bytes = b""  # shared with the match hosts: every message between them is sealed with it
    dashboard: Web | None = None  # where the experimenter's dashboard is served (services/study/dashboard.py)
    dashboard_token: str = ""  # ... to whoever shows this token


SERVING, WEB = Serving(), Web()


SERVING, WEB = Serving(), Web()


def check_tls(cert: Path | None, key: Path | None) -> None:
    """Refuse (UsageError) TLS files that would stop the server as it starts serving: a certificate
    without its key or a key without its certificate, or files that are no PEM certificate chain
    and its private key (the server found out only once its pool had started)."""
    if (cert is None) != (key is None):
        missing, given = ("--key", cert) if key is None else ("--cert", key)
        raise UsageError("--cert/--key", given, f"{missing} is missing: give both, or neither")
    if cert is None:
        return
    try:
        Web(cert=cert, key=key).tls()
    except (ssl.SSLError, OSError) as error:
        why = getattr(error, "reason", None) or error
        problem = f"not a PEM certificate chain and its key ({why})"
        raise UsageError("--cert/--key", f"{cert} {key}", problem) from None
