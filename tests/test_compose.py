"""The system as containers: compose.yaml against the Compose Specification, and `docker compose up`
of a full adaptive match on a real engine.

The engine test installs Debian's docker.io, docker-compose and debootstrap (docker/install-engine),
starts dockerd unless one already runs (and then stops it by its pid), builds the base image with
debootstrap (no image registry is reachable) and the wheelhouse on the host, builds the image with
no network at all, runs compose.yaml as it ships, and reads the recording the match left in the
volume; then sweep workers started by `docker compose run`, and a person in Chromium through the
human profile. They skip, with the reason, where the engine cannot be installed or started.

Compose tool: Debian's docker-compose 1.29.2, signed by the same archive as the engine and needing
no build plugin; the Compose Specification check (check-jsonschema's vendored schema) keeps the
file valid for Compose v2 as well.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import wait_in_page

from services.adapter.core import initial_policy
from services.population.adaptive import AdapterConfig
from services.recorder.recording import load, replay
from shared import keys
from shared.bus import free_endpoint

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "compose.yaml"
BASE = "tsf-python:3.11-bookworm"  # docker/base-image's default
IMAGE = "tsf:compose-test"
MATCH_SERVICES = ("sim", "agent-bait", "agent-shooter", "adapter", "recorder")


def _run(command: list[str], timeout: float, env: dict[str, str] | None = None, log: Path | None = None):
    """Run a command to its end; its output goes to `log` (kept for the failure message) or is captured."""
    if log is None:
        return subprocess.run(command, cwd=ROOT, env=env, timeout=timeout, capture_output=True, text=True)
    with log.open("w") as out:
        return subprocess.run(
            command, cwd=ROOT, env=env, timeout=timeout, stdout=out, stderr=subprocess.STDOUT
        )


def _tail(text: str, lines: int = 30) -> str:
    return "\n".join(text.splitlines()[-lines:])


def _check_schema(path: Path) -> subprocess.CompletedProcess:
    return _run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec", str(path)], 60
    )


def test_compose_file_follows_the_compose_specification(tmp_path: Path) -> None:
    checked = _check_schema(COMPOSE)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    text = COMPOSE.read_text()
    # Compose v1 (Debian's docker-compose) rejects the newest top-level keys; `version` is obsolete.
    assert not any(line.startswith(("version:", "name:", "develop:")) for line in text.splitlines())
    broken = tmp_path / "compose.yaml"
    broken.write_text(text.replace("\n  sim:\n", "\n  sim:\n    restart_policy: always\n", 1))
    assert _check_schema(broken).returncode != 0, "the schema check accepts an unknown service key"


def test_the_healthcheck_probe_finds_only_a_live_token(bus, wait_until) -> None:  # noqa: ANN001 - conftest's
    """`tsf alive`, the services' healthcheck, asks the hub as a client: a seat's token there is
    found; a missing or withdrawn one, or an unreachable hub, is not."""
    bus.open(listen=True)  # the hub
    token = bus.open().liveliness().declare_token(keys.alive("probe", "agent", "bait"))

    def probe(role: str, endpoint: str = bus.endpoint) -> int:
        command = [
            sys.executable,
            "-m",
            "services.commands",
            "alive",
            "--match",
            "probe",
            "--service",
            "agent",
        ]
        return _run([*command, "--role", role, "--connect", endpoint], 60).returncode

    assert probe("bait") == 0
    assert probe("shooter") == 1
    assert probe("bait", free_endpoint()) == 1
    token.undeclare()
    assert wait_until(lambda: probe("bait") == 1, timeout=10)


def _docker_ok() -> bool:
    return shutil.which("docker") is not None and _run(["docker", "info"], 30).returncode == 0


@pytest.fixture(scope="module")
def engine(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """A running engine: the one already up, or dockerd started here and stopped by its pid after."""
    if os.geteuid() != 0:
        pytest.skip("the engine test installs and starts dockerd: it needs root")
    installed = _run([str(ROOT / "docker/install-engine")], 600)
    if installed.returncode != 0:
        pytest.skip(f"cannot install the engine: {_tail(installed.stdout + installed.stderr)}")
    if _docker_ok():
        yield
        return
    logs = tmp_path_factory.mktemp("dockerd")
    with (logs / "dockerd.log").open("w") as out:
        dockerd = subprocess.Popen(
            ["dockerd", "--pidfile", str(logs / "dockerd.pid")], stdout=out, stderr=subprocess.STDOUT
        )
    try:
        deadline = time.monotonic() + 60
        while not _docker_ok():
            if dockerd.poll() is not None or time.monotonic() > deadline:
                pytest.skip(f"dockerd did not start:\n{_tail((logs / 'dockerd.log').read_text())}")
            time.sleep(1)
        yield
    finally:
        dockerd.terminate()
        try:
            dockerd.wait(60)
        except subprocess.TimeoutExpired:
            dockerd.kill()
            dockerd.wait()


def _step(
    name: str, command: list[str], timeout: float, logs: Path, took: dict[str, float], **env: str
) -> str:
    """Run one timed step of the engine tests; its output goes to a log, shown if it fails."""
    started = time.monotonic()
    done = _run(command, timeout, {**os.environ, **env}, logs / f"{name}.log")
    took[name] = time.monotonic() - started
    log = (logs / f"{name}.log").read_text()
    assert done.returncode == 0, f"{name} failed:\n{_tail(log, 60)}"
    return log


@pytest.fixture(scope="module")
def inputs(engine: None, tmp_path_factory: pytest.TempPathFactory) -> dict[str, float]:
    """What the image is built from, made once: the base image and the wheelhouse (each kept when
    already there). The test image is removed, so that the first compose command builds it from this
    checkout. Returns the seconds each step took."""
    took: dict[str, float] = {}
    logs = tmp_path_factory.mktemp("inputs")
    _step("base-image", [str(ROOT / "docker/base-image"), BASE], 900, logs, took)
    _step("wheelhouse", [str(ROOT / "docker/wheelhouse")], 900, logs, took)
    _run(["docker", "image", "rm", "--force", IMAGE], 120)
    return took


def _compose_env(**variables: str) -> dict[str, str]:
    """The environment of a compose run here: its own project, the offline build on the local base."""
    return {
        **os.environ,
        "COMPOSE_PROJECT_NAME": f"tsftest{uuid.uuid4().hex[:8]}",
        "TSF_BASE": BASE,
        "TSF_OFFLINE": "1",
        "TSF_BUILD_NETWORK": "none",
        "TSF_IMAGE": IMAGE,
        **variables,
    }


def _containers(env: dict[str, str]) -> dict[str, str]:
    """Service name -> container id of the compose project in `env`."""
    ids = {}
    for service in MATCH_SERVICES:
        found = _run(["docker-compose", "ps", "-q", service], 60, env).stdout.split()
        assert found, f"no {service} container"
        ids[service] = found[0]
    return ids


def _inspect(container: str, template: str) -> str:
    return _run(["docker", "inspect", "--format", template, container], 60).stdout.strip()


@pytest.mark.docker
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_compose_up_plays_a_full_adaptive_match(
    inputs: dict[str, float], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    took = dict(inputs)
    match = f"compose-{uuid.uuid4().hex[:8]}"
    # The grown library's agent (the previous default; the tuned one plays TS1 with every group) with
    # GB1, a slow circle: the agent must switch (below).
    monkeypatch.setenv("TSF_LIBRARY", "grown")
    env = _compose_env(TSF_MATCH=match, TSF_BAIT="GB1")
    try:
        log = _step("up", ["docker-compose", "up", "--no-color"], 900, tmp_path, took, **env)
        containers = _containers(env)
        exits = {service: _inspect(c, "{{.State.ExitCode}}") for service, c in containers.items()}
        assert exits == dict.fromkeys(MATCH_SERVICES, "0"), (exits, _tail(log, 60))
        for service, container in containers.items():  # each healthcheck passed at least once
            codes = _inspect(container, "{{range .State.Health.Log}}{{.ExitCode}} {{end}}").split()
            assert "0" in codes, f"{service} never healthy: {codes}"
        copied = _run(
            ["docker", "cp", f"{containers['recorder']}:/recordings/{match}.tsflog", str(tmp_path)], 60
        )
        assert copied.returncode == 0, copied.stderr
    finally:
        _run(["docker-compose", "down", "--volumes", "--remove-orphans"], 300, env)
    print("compose test, seconds per step: " + ", ".join(f"{k} {v:.0f}" for k, v in took.items()))

    recording = load(tmp_path / f"{match}.tsflog")
    assert recording.clean and recording.start is not None and recording.summary is not None
    assert recording.summary.frame == 1800  # compose.yaml's default: a full one-minute match
    # Real time on a shared machine: the sim never waits, so a starved recorder may miss a state;
    # the log then says so with a gap record. More than 1% missing is a fault, not load.
    assert len(recording.states) + recording.missing_frames == 1801
    assert recording.missing_frames <= 18, recording.gaps
    for role in ("bait", "shooter"):
        frames = {a.frame for _, a in recording.actions if a.role == role}
        assert len(frames) > 1700, f"{role} answered only {len(frames)} of 1800 states"
    if recording.gaps:  # a missed state holds the actions the sim applied: no replay past it
        print(f"recording has gaps {recording.gaps}: replay not checked")
    else:
        assert replay(recording) == []  # the recording re-simulates to the same state hashes
    assert recording.adapter, "no AdapterStatus in the recording: the adapter did not run"
    assert {(s.role, s.window) for s in recording.adapter} == {("shooter", 400)}
    assert recording.adapter[-1].filled == 400
    # The adaptive loop through the containers: GB1's partner group (G4) plays best with GS2, not
    # the initial policy (the best on average, GS1), so the adapter switched the shooter, and the
    # shooter agent plays what the adapter chose last.
    assert recording.switches and {s.sender for s in recording.switches} == {"adapter"}
    shooter = [a for _, a in recording.actions if a.role == "shooter"]
    initial = initial_policy(AdapterConfig("shooter", 400, partners="groups"))
    assert shooter[0].policy == initial and shooter[-1].policy == recording.adapter[-1].policy
    assert recording.switches[-1].policy == recording.adapter[-1].policy


@pytest.mark.docker
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_compose_run_starts_sweep_workers_for_a_coordinator_on_the_host(inputs: dict, tmp_path: Path) -> None:
    """Two `docker compose run -d worker` containers (they start the router) play the jobs of a
    `tsf sweep` on the host, which reaches them through the router's published port."""
    port = free_endpoint().rsplit(":", 1)[1]
    env = _compose_env(TSF_ROUTER_PORT=port, TSF_SWEEP="compose")
    try:
        for _ in range(2):
            started = _run(["docker-compose", "run", "-d", "worker"], 900, env)
            assert started.returncode == 0, _tail(started.stdout + started.stderr)
        table = tmp_path / "table.json"
        sweep = [sys.executable, "-m", "services.commands", "sweep", "--sweep", "compose", "--workers", "0"]
        sweep += ["--games", "4", "--chunk", "1", "--bait", "B5", "--shooter", "S5", "--out", str(table)]
        swept = _run([*sweep, "--connect", f"tcp/127.0.0.1:{port}"], 300)
        assert swept.returncode == 0, _tail(swept.stdout + swept.stderr)
        workers = _run(["docker", "ps", "-aq", "--filter", f"name={env['COMPOSE_PROJECT_NAME']}_worker"], 60)
        assert _run(["docker", "wait", *workers.stdout.split()], 60).returncode == 0  # they stop after it
        logs = [_run(["docker", "logs", c], 60) for c in workers.stdout.split()]
    finally:
        _run(["docker-compose", "--profile", "sweep", "down", "--volumes", "--remove-orphans"], 300, env)
    done = [int(m) for log in logs for m in re.findall(r"did (\d+) jobs", log.stdout + log.stderr)]
    assert len(done) == 2 and sum(done) == 4, done  # both workers ran, and together did every job
    assert table.exists()


@pytest.mark.docker
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_workers_started_through_the_sdk_compute_the_table_and_down_removes_them(
    inputs: dict, tmp_path: Path
) -> None:
    """`tsf workers up` (the Docker SDK) starts two worker containers from the image built from this
    checkout; a `tsf sweep` on the host with no local workers reaches them through a router; the
    table equals the one computed in-process, and `tsf workers down` leaves no container behind."""
    from services.table.table import Table, assemble, jobs, run_job

    env = _compose_env()
    built = _run(["docker-compose", "build", "sim"], 900, env)
    assert built.returncode == 0, _tail(built.stdout + built.stderr)
    endpoint, sweep, tsf = (
        free_endpoint(),
        f"sdk{uuid.uuid4().hex[:6]}",
        [sys.executable, "-m", "services.commands"],
    )
    router = subprocess.Popen([*tsf, "router", "--listen", endpoint])
    table, listed = tmp_path / "table.json", ""
    try:
        up = _run(
            [
                *tsf,
                "workers",
                "up",
                "--count",
                "2",
                "--sweep",
                sweep,
                "--image",
                IMAGE,
                "--connect",
                endpoint,
            ],
            120,
        )
        assert up.returncode == 0, _tail(up.stdout + up.stderr)
        listed = _run([*tsf, "workers", "ls", "--sweep", sweep], 60).stdout
        sweep_command = [*tsf, "sweep", "--sweep", sweep, "--workers", "0", "--games", "4", "--chunk", "1"]
        sweep_command += ["--bait", "B5", "--shooter", "S5", "--out", str(table)]
        swept = _run([*sweep_command, "--mode", "client", "--connect", endpoint], 300)
        assert swept.returncode == 0, _tail(swept.stdout + swept.stderr)
    finally:
        down = _run([*tsf, "workers", "down", "--sweep", sweep], 120)
        router.terminate()
        router.wait(30)
    assert listed.count(sweep) >= 2, listed
    assert down.returncode == 0 and "removed 2 worker" in down.stdout, down.stdout + down.stderr
    assert _run(["docker", "ps", "-aq", "--filter", f"label=tsf.sweep={sweep}"], 60).stdout.strip() == ""
    reference = {job.id: run_job(job) for job in jobs(["B5"], ["S5"], 4, 1)}
    assert Table.load(table).results == assemble(["B5"], ["S5"], 4, reference, 1).results
    missing = _run([*tsf, "workers", "up", "--connect", endpoint, "--image", "tsf:absent"], 60)
    assert missing.returncode == 1 and "docker build -t tsf:absent" in missing.stderr.splitlines()[-1]


@pytest.mark.docker
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_the_human_profile_seats_a_person_from_the_browser(inputs: dict, tmp_path: Path) -> None:
    """`docker compose --profile human up --scale agent-bait=0`: a person plays the bait from Debian's
    Chromium through the published port, with the adaptive shooter; the recording says so."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it)")
    sync_api = pytest.importorskip("playwright.sync_api")
    port, match, frames = free_endpoint().rsplit(":", 1)[1], f"human-{uuid.uuid4().hex[:8]}", 300
    env = _compose_env(
        TSF_MATCH=match, TSF_FRAMES=str(frames), TSF_BAIT="human", TSF_HUMAN_TOKEN="t0k", TSF_HUMAN_PORT=port
    )
    try:
        up = ["docker-compose", "--profile", "human", "up", "-d", "--scale", "agent-bait=0"]
        started = _run(up, 900, env)
        assert started.returncode == 0, _tail(started.stdout + started.stderr)
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page()
            deadline = time.monotonic() + 60
            while True:  # the gateway's page, once its container serves it (Docker's port proxy
                try:  # accepts connections before the container listens, so check it is the page)
                    page.goto(f"http://127.0.0.1:{port}/?role=bait&token=t0k")
                    if page.evaluate("typeof window.tsf") == "object":
                        break
                except sync_api.Error:
                    pass
                assert time.monotonic() < deadline, "the human gateway never served its page"
                time.sleep(1)
            wait_in_page(page, "window.tsf.phase === 'instructions'", 30_000)
            page.keyboard.press("Space")  # start
            wait_in_page(page, "window.tsf.phase === 'playing'", 60_000)
            page.keyboard.down("ArrowLeft")
            page.wait_for_timeout(1000)
            page.keyboard.up("ArrowLeft")
            wait_in_page(page, "window.tsf.phase === 'ended'", frames / 30 * 1000 + 30_000)
            browser.close()
        recorder = _run(["docker-compose", "ps", "-q", "recorder"], 60, env).stdout.strip()
        assert _run(["docker", "wait", recorder], 60).stdout.strip() == "0"
        copied = _run(["docker", "cp", f"{recorder}:/recordings/{match}.tsflog", str(tmp_path)], 60)
        assert copied.returncode == 0, copied.stderr
    finally:
        _run(["docker-compose", "--profile", "human", "down", "--volumes", "--remove-orphans"], 300, env)

    recording = load(tmp_path / f"{match}.tsflog")
    assert recording.summary is not None and recording.summary.frame == frames
    shooter = "adaptive-T400-bayes-dwell-ood-guard_partners-groups"  # the tuned library's agent, by default
    assert recording.start.policies == {"bait": "human", "shooter": shooter}
    bait = [a for _, a in recording.actions if a.role == "bait"]
    assert bait and all(a.sender == "human/bait" for a in bait), "only the person played the bait"
    assert sum(1 for a in bait if a.action // 4 == 1) >= 15, "about a second of held left arrow arrived"
    assert recording.adapter, "the adapter watched the person"
