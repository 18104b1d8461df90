"""The study as a crowd-sourced participant meets it on the open internet: Debian's Chromium over
TLS (a self-signed certificate made here with openssl), a worker id in the link, the completion
code at the end, one participation per worker id, the page's security headers, and sockets from
other origins refused. Skipped, with the reason, where Chromium or openssl is missing."""

from __future__ import annotations

import asyncio
import shutil
import ssl
import subprocess
import urllib.request
from concurrent.futures import ThreadPoolExecutor

import pytest
import websockets
from conftest import CHROMIUM

from services.human.gateway import Web
from services.study.admission import DECLINED, TAKEN
from services.study.core import StudyConfig, Variant
from services.study.serving import Serving

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or shutil.which("openssl") is None,
    reason="Debian's chromium or openssl is not installed",
)


@pytest.fixture
def tls_study(tmp_path, study_server):
    """A one-trial study served over TLS with a fresh self-signed certificate: (url, stop, server)."""
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1",
         "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True,
    )  # fmt: skip
    config = StudyConfig("tls", (Variant.read("s", "B5", "S5"),), trials=1, trial_seconds=2.0, end="Thanks.")
    stop, url, server = study_server(config, tmp_path / "study", Serving(), Web(port=0, cert=cert, key=key))
    return url, stop, server


def test_a_crowd_worker_takes_part_once_over_tls_and_gets_a_completion_code(browser, tls_study):
    expect = pytest.importorskip("playwright.sync_api").expect
    url, stop, server = tls_study
    assert url.startswith("https://")
    context = browser.new_context(ignore_https_errors=True)  # the certificate is self-signed
    page = context.new_page()
    response = page.goto(url + "?workerId=W-17")
    headers = response.headers
    assert "frame-ancestors 'none'" in headers["content-security-policy"]
    assert headers["x-frame-options"] == "DENY" and "server" not in headers  # no version banner
    title = page.locator("#title")  # waits read the page (the CSP forbids evaluating strings)
    expect(title).to_have_text("Before we start", timeout=20_000)
    page.click("#go")
    expect(title).to_contain_text("Session 1 of 1", timeout=20_000)
    page.click("#go")
    expect(title).to_have_text("The end", timeout=240_000)
    text = page.locator("#text").inner_text()
    assert "Thanks." in text and "Your completion code: " in text
    code = text.rsplit(": ", 1)[1].strip()
    context.close()

    again = browser.new_context(ignore_https_errors=True).new_page()  # no saved id: a new arrival
    again.goto(url + "?workerId=W-17")
    expect(again.locator("#title")).to_have_text("Not possible", timeout=20_000)
    assert TAKEN in again.locator("#text").inner_text()

    stop.set()
    study = server.result(timeout=60)
    (participant,) = study.participants.values()
    assert (participant.worker, participant.code) == ("W-17", code)
    assert [a["status"] for a in participant.attempts] == ["done"]


def test_a_participant_who_declines_gets_a_closing_page(browser, tls_study):
    expect = pytest.importorskip("playwright.sync_api").expect
    url, stop, server = tls_study
    page = browser.new_context(ignore_https_errors=True).new_page()
    page.goto(url + "?workerId=W-18")
    expect(page.locator("#title")).to_have_text("Before we start", timeout=20_000)
    assert "play 1 game of 2 seconds each" in page.locator("#text").inner_text()
    page.click("#no")
    expect(page.locator("#text")).to_have_text(DECLINED, timeout=20_000)
    assert page.locator("#go").is_hidden() and page.locator("#no").is_hidden()
    page.wait_for_timeout(500)  # the socket closed: the page stays as it is
    expect(page.locator("#text")).to_have_text(DECLINED)
    stop.set()
    assert server.result(timeout=60).participants == {}


def test_sockets_from_other_origins_are_refused_and_errors_say_nothing_internal(tls_study):
    url, _, _ = tls_study
    insecure = ssl.create_default_context()
    insecure.check_hostname, insecure.verify_mode = False, ssl.CERT_NONE
    socket = url.replace("https", "wss", 1) + "ws"

    async def open_from(origin: str) -> int:
        try:
            async with websockets.connect(socket, ssl=insecure, origin=origin):
                return 101
        except websockets.InvalidStatus as refused:
            assert "server" not in refused.response.headers
            assert refused.response.body == b"forbidden\n"
            return refused.response.status_code

    with ThreadPoolExecutor(1) as pool:  # Playwright's loop may be running in this thread
        assert pool.submit(asyncio.run, open_from("https://evil.example")).result() == 403
        assert pool.submit(asyncio.run, open_from(url.rstrip("/"))).result() == 101  # the page's own
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(url + "no-such-page", context=insecure)
    assert missing.value.code == 404 and missing.value.read() == b"not found\n"
