"""`tsf match` as people run it, each in a real process with its own services: default ids that never
collide, a recording that is never appended to, and signals that end every process it started."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from services.recorder.log import read_log
from services.recorder.recording import load, replay
from services.runtime.launch import RECORDER_NICE, SIM_RAISE
from services.sim.pool import BUS_BELOW

SHORT = ("--lockstep", "--duration", "0.3")  # 9 frames


PARENT, SESSION = 1, 3  # fields of /proc/PID/stat after the command's name


def processes(field: int, value: int) -> dict[int, str]:
    """The live processes whose stat `field` is `value`, and their command lines, from /proc."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            command = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue  # it ended while we looked
        if int(fields[field]) == value and fields[0] != "Z":
            found[int(stat.parent.name)] = command
    return found


def children(pid: int) -> dict[int, str]:
    """The live child processes of `pid` and their command lines."""
    return processes(PARENT, pid)


def in_session(session: int) -> dict[int, str]:
    """The live processes of session `session`: a launcher started with start_new_session=True and
    everything it started, at any depth, even once re-parented to init after the launcher died
    (only a process that calls setsid leaves it). Found by session, never by name, so that two
    runs of the suite cannot see each other's processes."""
    return processes(SESSION, session)


def alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture
def tsf(tmp_path: Path) -> Iterator[Callable[..., subprocess.Popen]]:
    """Start `tsf ARGS...` in a session of its own, output to files; whatever is left of its process
    group is killed at teardown, so a failing test leaves nothing behind."""
    started: list[subprocess.Popen] = []

    def start(*args: str) -> subprocess.Popen:
        n = len(started)
        command = [sys.executable, "-m", "services.commands", *args]
        with (tmp_path / f"out{n}").open("w") as out, (tmp_path / f"err{n}").open("w") as err:
            started.append(subprocess.Popen(command, stdout=out, stderr=err, start_new_session=True))
        started[-1].err = tmp_path / f"err{n}"  # type: ignore[attr-defined]
        return started[-1]

    yield start
    for process in started:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


@pytest.fixture
def tsf_match(tsf, tmp_path: Path) -> Callable[..., subprocess.Popen]:
    """`tsf match --out tmp_path ARGS...`, as `tsf` starts it."""
    return lambda *args: tsf("match", "--out", str(tmp_path), *args)


def recorded(log: Path) -> int:
    """The records of a recording so far: none until its header is written."""
    try:
        return len(read_log(log)[0])
    except (OSError, ValueError):
        return 0


def last_line(process: subprocess.Popen) -> str:
    text = process.err.read_text()  # type: ignore[attr-defined]
    assert "Traceback" not in text, text
    return text.strip().splitlines()[-1]


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_matches_started_together_get_their_own_recordings_and_an_id_is_never_reused(tsf_match, tmp_path):
    first, second = tsf_match(*SHORT), tsf_match(*SHORT)  # the same second, the default id
    assert first.wait(120) == 0 and second.wait(120) == 0
    paths = sorted(tmp_path.glob("*.tsflog"))
    assert len(paths) == 2
    for path in paths:
        recording = load(path)
        assert recording.problems() == [] and replay(recording) == []

    taken, before = paths[0].stem, paths[0].read_bytes()
    refused = tsf_match(*SHORT, "--match", taken)
    assert refused.wait(60) == 2
    refusal = f"{paths[0]} exists; choose another id, or --overwrite to keep it aside"
    assert last_line(refused) == f"tsf match: --match {taken}: {refusal}"
    assert paths[0].read_bytes() == before and not children(refused.pid)

    again = tsf_match(*SHORT, "--match", taken, "--overwrite")
    assert again.wait(120) == 0
    assert (tmp_path / f"{taken}.tsflog.replaced-1").read_bytes() == before
    assert (tmp_path / f"{taken}.tables.replaced-1" / f"{taken}.states.parquet").exists()
    recording = load(paths[0])
    assert recording.problems() == [] and recording.starts == 1 and replay(recording) == []


def nice(pid: int, task: int | None = None) -> int:
    """A process's (or one of its threads') nice value, field 19 of its stat in /proc."""
    stat = Path("/proc") / str(pid) / (f"task/{task}/stat" if task else "stat")
    return int(stat.read_text().rsplit(")", 1)[1].split()[16])


def niced(pid: int) -> dict[int, int]:
    """Each thread of a process and its nice value."""
    return {
        int(task.name): nice(pid, int(task.name)) for task in (Path("/proc") / str(pid) / "task").iterdir()
    }


def may_raise_priority() -> bool:
    """Whether this process has CAP_SYS_NICE (root's, unless a container takes it away)."""
    status = Path("/proc/self/status").read_text()
    return bool(int(re.search(r"CapEff:\s*([0-9a-f]+)", status).group(1), 16) >> 23 & 1)


def test_the_sim_plays_above_its_matchs_other_processes(tsf_match, tmp_path, wait_until):
    """Frames on time: at its first frame the sim raises every thread of its own SIM_RAISE steps
    above the launcher (where permitted), above every start-up; the recorder runs RECORDER_NICE
    below, the agents and the adapter at the launcher's priority (services/launch.py)."""
    match = tsf_match("--duration", "60", "--match", "niced", "--adaptive", "shooter")
    log = tmp_path / "niced.tsflog"
    assert wait_until(lambda: recorded(log) > 20, timeout=60)  # past the first frame
    base = nice(match.pid)
    sim = base - SIM_RAISE if may_raise_priority() else base
    expected = {"sim": sim, "agent": base, "adapter": base}
    expected["recorder"] = min(19, base + RECORDER_NICE)
    started = {pid: command.split()[3] for pid, command in children(match.pid).items()}
    assert sorted(started.values()) == ["adapter", "agent", "agent", "recorder", "sim"]
    for pid, service in started.items():
        threads = [int(task.name) for task in (Path("/proc") / str(pid) / "task").iterdir()]
        assert {nice(pid, task) for task in threads} == {expected[service]}, service
    match.terminate()
    assert match.wait(30) == 1


@pytest.mark.skipif(not (may_raise_priority() and shutil.which("setpriv")), reason="needs root and setpriv")
def test_a_sim_not_permitted_to_raise_its_priority_keeps_it_and_says_so_once():
    """As in a container without CAP_SYS_NICE (dropped here by setpriv): no error, one log line."""
    script = (
        "import logging, os, threading, time; logging.basicConfig(level=logging.INFO)\n"
        "from services.sim.service import _raise_priority\n"
        "threading.Thread(target=time.sleep, args=(1,)).start()\n"
        "_raise_priority(5); print(os.getpriority(os.PRIO_PROCESS, 0))\n"
    )
    drop = ["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice"]
    done = subprocess.run([*drop, sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and int(done.stdout) == os.getpriority(os.PRIO_PROCESS, 0)
    assert done.stderr.count("not permitted to raise the priority") == 1, done.stderr


def as_ordinary_user() -> list[str] | None:
    """The command prefix that runs a process as an ordinary user runs it (CAP_SYS_NICE dropped by
    setpriv where this suite has it); None where that cannot be done here."""
    if not may_raise_priority():
        return []
    return (
        ["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice"] if shutil.which("setpriv") else None
    )


POOL_LAUNCHER = """
import os, sys, tempfile, time
from pathlib import Path
from services.runtime.pool import Pool
from shared.processes import spawner
with Pool("niced", Path(tempfile.mkdtemp()), adaptive=False) as pool:
    pids = {name: child.pid for name, child in pool.processes.children.items()}
    print(spawner(), pids["sim"], pids["agent"], pids["recorder"], flush=True)
    sys.stdin.read()
"""


@pytest.mark.skipif(as_ordinary_user() is None, reason="needs setpriv to drop CAP_SYS_NICE")
def test_where_the_sim_may_not_raise_itself_everything_else_of_a_pool_steps_below_it(wait_until):
    """As an ordinary user (the sim cannot leave its launcher's priority): the launcher (a study
    server, a match host) and the pool's agent step SIM_RAISE below the sim, its recorder
    RECORDER_NICE further, and the sim's own bus threads BUS_BELOW below its clock; the spawner,
    which starts a sim again or for another pool, keeps the launcher's first priority."""
    base = os.getpriority(os.PRIO_PROCESS, 0)
    launcher = subprocess.Popen(
        [*as_ordinary_user(), sys.executable, "-c", POOL_LAUNCHER],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        spawner, sim, agent, recorder = map(int, launcher.stdout.readline().split())
        below = {**{t: base + SIM_RAISE for t in niced(launcher.pid)}, spawner: base}
        assert wait_until(lambda: niced(launcher.pid) == below, timeout=10), niced(launcher.pid)
        bus = {**{t: base + BUS_BELOW for t in niced(sim)}, sim: base}  # the clock: the sim's main thread
        assert wait_until(lambda: niced(sim) == bus, timeout=10), niced(sim)
        assert set(niced(agent).values()) == {base + SIM_RAISE}
        assert set(niced(recorder).values()) == {min(19, base + SIM_RAISE + RECORDER_NICE)}
    finally:
        launcher.stdin.close()
        assert launcher.wait(60) == 0


SIGNALS = [signal.SIGTERM, signal.SIGHUP, signal.SIGINT, signal.SIGKILL]


def ended(process: subprocess.Popen, sig: signal.Signals, line: str) -> bool:
    """Whether the launcher ended as it should on `sig`: killed, or exit status 1 and one line."""
    if sig == signal.SIGKILL:
        return process.wait(20) == -signal.SIGKILL
    return process.wait(30) == 1 and last_line(process) == line


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: s.name)
def test_a_signal_ends_the_match_and_every_process_it_started(tsf_match, tmp_path, wait_until, sig):
    """SIGKILL leaves the match no time to end its processes: each asked the kernel for SIGTERM
    when its launcher dies (shared/processes.py)."""
    match = tsf_match("--duration", "60", "--match", "signalled")
    log = tmp_path / "signalled.tsflog"
    assert wait_until(lambda: recorded(log) > 20, timeout=60)  # under way
    started = children(match.pid)
    assert sorted(command.split()[3] for command in started.values()) == ["agent", "agent", "recorder", "sim"]
    os.kill(match.pid, sig)
    assert ended(match, sig, "tsf match: match signalled was stopped before its end; its processes ended")
    assert wait_until(lambda: not in_session(match.pid), timeout=20), in_session(match.pid)


# Launchers of worker processes, as they are started for a long run: `tsf worker` processes of the
# job system, for a sweep and for eval.
LAUNCHERS = {
    "sweep": ("sweep", "--workers", "2", "--games", "10000", "--out", "{tmp}/table.json"),
    "eval": ("eval", "--workers", "2", "--out", "{tmp}/eval"),
}
STOPPED = {
    "sweep": "tsf sweep: stopped; run the same command again to resume from {tmp}/table.json.journal",
    "eval": "tsf eval: stopped; run the same command again to resume from {tmp}/eval/eval.journal",
}


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: s.name)
@pytest.mark.parametrize("launcher", LAUNCHERS)
def test_a_signal_ends_a_launcher_and_its_workers(tsf, tmp_path, wait_until, launcher, sig):
    process = tsf(*(arg.format(tmp=tmp_path) for arg in LAUNCHERS[launcher]))
    assert wait_until(lambda: len(children(process.pid)) == 2, timeout=60)
    os.kill(process.pid, sig)
    assert ended(process, sig, STOPPED[launcher].format(tmp=tmp_path, sig=sig.name))
    assert wait_until(lambda: not in_session(process.pid), timeout=30), in_session(process.pid)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=lambda s: s.name)
def test_a_worker_with_slots_stopped_or_killed_leaves_no_process_behind(tsf, tmp_path, wait_until, sig):
    """`tsf worker --slots 2`, waiting for a coordinator: its slots' processes end with it."""
    worker = tsf("worker", "--slots", "2", "--sweep", tmp_path.name[-30:], "--listen", "tcp/127.0.0.1:0")
    assert wait_until(lambda: len(children(worker.pid)) == 2, timeout=60)
    os.kill(worker.pid, sig)
    worker.wait(30)
    assert wait_until(lambda: not in_session(worker.pid), timeout=10), in_session(worker.pid)


def test_a_service_that_fails_fails_the_match(tsf_match, tmp_path, wait_until):
    match = tsf_match("--duration", "3", "--match", "failing")
    log = tmp_path / "failing.tsflog"
    assert wait_until(lambda: recorded(log) > 20, timeout=60)
    [recorder] = [pid for pid, command in children(match.pid).items() if command.split()[3] == "recorder"]
    os.kill(recorder, signal.SIGKILL)
    assert match.wait(30) == 1
    assert last_line(match) == "tsf match: match failing: recorder exited with status -9"


def test_a_policy_that_fails_mid_match_plays_no_op_and_the_match_exits_1(tsf, tmp_path, monkeypatch):
    """The match runs to its end on the sim's clock; the agent says it once; the recording has a
    policy_failure event per failed frame with its count; the summary names it; exit status 1."""
    (tmp_path / "lab_live.py").write_text(
        "class Raises:\n    key, role, view = 'raises', 'bait', 'world'\n"
        "    def reset(self, seed=None):\n        self.t = 0\n"
        "    def act(self, obs):\n        self.t += 1\n"
        "        if self.t > 30:\n            raise RuntimeError('boom')\n        return 2\n"
    )
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    match = tsf("match", "--out", str(tmp_path), "--duration", "2", "--match", "failing-policy",
                "--bait", "lab_live:Raises", "--lockstep")  # fmt: skip
    assert match.wait(60) == 1
    recording = load(tmp_path / "failing-policy.tsflog")
    failed = recording.summary.failures["bait"]  # frames 30..59, and the last state's if answered in time
    assert set(recording.summary.failures) == {"bait"} and failed in (30, 31)
    assert recording.summary.frame == 60
    said = f"a policy failed and played no-op: the bait's on {failed} frames (policy_failure events in"
    assert last_line(match).startswith(f"tsf match: match failing-policy: {said}")
    assert match.err.read_text().count("the policy failed and plays no-op") == 1  # type: ignore[attr-defined]
    events = [e for e in recording.events if e.kind == "policy_failure"]
    assert [e.detail.split(":")[0] for e in events] == [str(n) for n in range(1, failed + 1)]
    assert events[0].role == "bait" and "raises at frame 30: RuntimeError: boom" in events[0].detail
