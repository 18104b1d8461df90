"""Child processes that never outlive the launcher that started them.

A launcher (`tsf match`, `play`, `study`, `sweep`, `eval`, `calibrate-adapter`) ends its children
itself when it is stopped (SIGINT, SIGTERM or SIGHUP): `Processes` on exit, a pool on terminate.
A launcher that cannot clean up (SIGKILL, the out-of-memory killer, a crashed interpreter) is
covered by the kernel: each child asks Linux for SIGTERM when its parent dies (prctl
PR_SET_PDEATHSIG) as its first act, and ends at once if the parent is already gone. The signal
comes when the thread that started the child ends, so every child is started by one thread of the
launcher that lives as long as the launcher does (the spawner).

Workers of a `concurrent.futures.ProcessPoolExecutor` (the study's judge) are started by
multiprocessing, not here: they call `end_with_parent` first, so that they, and with them
multiprocessing's resource tracker, end when their launcher does.

Priorities are relative to the launcher's own, the spawner's (it starts at the priority of the
first thread that starts a child): a child is started `nice` steps below it (and the sim raises
itself some steps above, services/sim/service.py), so a launcher run under `nice` keeps the order
of its processes, shifted. Where the sim may not raise itself (`may_raise`; an ordinary user), a
launcher steps its own threads below the spawner instead (`step_down`): the spawner keeps the
launcher's first priority, so a sim started later, again or for another pool, still starts above.

A child's output comes back through the launcher, line by line, written to the launcher's own
stdout and stderr as they are then: inside a live display (`tsf match`'s scoreboard, a progress bar)
rich puts each line above it, instead of the child's line running onto the display's.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import IO

PARENT = "TSF_PARENT"  # environment: the pid of the launcher a `tsf` child must not outlive
_SPAWNER = ThreadPoolExecutor(1, thread_name_prefix="spawner")  # its thread: at the first start


def _new_spawner() -> None:
    """In a forked child: a spawner of its own (the parent's thread is not there)."""
    global _SPAWNER
    _SPAWNER = ThreadPoolExecutor(1, thread_name_prefix="spawner")


os.register_at_fork(after_in_child=_new_spawner)
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent: int) -> None:
    """Have this process sent SIGTERM when `parent` dies (Linux; elsewhere only the check below),
    and end it now if `parent` is already gone (the child was re-parented before it could ask)."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG)")
    if os.getppid() != parent:
        os._exit(1)


def end_with_parent() -> None:
    """In a multiprocessing worker (a pool's initializer): exit as soon as the process that started
    it is gone, however it went. A launcher that was SIGKILLed, or crashed, never shuts its pool
    down, and its workers, waiting on a queue whose ends they hold themselves, ran on for hours,
    re-parented to init, and kept multiprocessing's resource tracker alive with them. The worker
    watches the pipe whose other end only its parent holds (multiprocessing's parent sentinel; a
    thread, since PR_SET_PDEATHSIG fires when the thread that started the worker ends, and a pool
    starts its workers from whichever thread submits first)."""
    parent = multiprocessing.parent_process()
    if parent is not None:
        threading.Thread(target=_exit_after, args=(parent,), name="end-with-parent", daemon=True).start()


def _exit_after(parent: multiprocessing.process.BaseProcess) -> None:
    parent.join()
    os._exit(1)


def adopt() -> None:
    """In a `tsf` process: if a launcher started it (PARENT is set), die with that launcher. The
    variable is removed, so that this process's own children are not taken for the launcher's."""
    parent = os.environ.pop(PARENT, "")
    if parent:
        die_with_parent(int(parent))


def threads() -> list[int]:
    """The ids of this process's threads (Linux keeps a nice value per thread); this one alone
    where there is no /proc."""
    try:
        return [int(task) for task in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def may_raise(steps: int) -> bool:
    """Whether a child started here may raise itself `steps` nice steps above the spawner's priority
    (CAP_SYS_NICE: root's, unless a container takes it away; or a nice limit, RLIMIT_NICE, that
    reaches that level: one that allows fewer steps is a refusal): tried on this thread and undone."""
    now = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, max(-20, os.getpriority(os.PRIO_PROCESS, spawner()) - steps))
    except PermissionError:
        return False
    os.setpriority(os.PRIO_PROCESS, 0, now)
    return True


def step_down(steps: int, above: int) -> None:
    """Put every thread of this process but `above` (a native thread id) at least `steps` nice steps
    below it (at most 19): what an ordinary user may do where raising is not permitted. Threads they
    start later inherit it; a second call with the same steps changes nothing."""
    level = min(19, os.getpriority(os.PRIO_PROCESS, above) + steps)
    for thread in threads():
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            if thread != above and os.getpriority(os.PRIO_PROCESS, thread) < level:
                os.setpriority(os.PRIO_PROCESS, thread, level)


def spawner() -> int:
    """The native id of the thread that starts this process's children (started by the first call
    here or to Processes.start, at that thread's priority)."""
    return _SPAWNER.submit(threading.get_native_id).result()


def _spawn(command: list[str], nice: int) -> subprocess.Popen:
    """On the spawner: start a child `nice` steps below the spawner's priority."""
    child = subprocess.Popen(
        command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        env={**os.environ, PARENT: str(os.getpid())},
    )  # fmt: skip
    if nice:  # set from here: a preexec_fn is unsafe in a process with threads (the study server)
        os.setpriority(os.PRIO_PROCESS, child.pid, min(19, os.getpriority(os.PRIO_PROCESS, 0) + nice))
    return child


class Processes:
    """Child `tsf` processes; all are ended (SIGTERM, then SIGKILL) on exit, and each dies with
    this process if it is killed first (adopt)."""

    def __init__(self) -> None:
        self.children: dict[str, subprocess.Popen] = {}
        self.ended: set[str] = set()  # the children still running at exit, which this ended
        self.relays: list[threading.Thread] = []

    def start(self, name: str, command: list[str], nice: int = 0) -> subprocess.Popen:
        """Start a child, from the spawner; `nice` > 0 steps below the spawner's priority (for work
        off the latency path; its threads inherit it)."""
        child = self.children[name] = _SPAWNER.submit(_spawn, command, nice).result()
        for pipe, stream in ((child.stdout, "stdout"), (child.stderr, "stderr")):
            relay = threading.Thread(target=_relay, args=(pipe, stream), name=f"{name}-{stream}", daemon=True)
            relay.start()
            self.relays.append(relay)
        return child

    def wait(self, name: str, timeout: float) -> int | None:
        try:
            return self.children[name].wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def failed(self) -> dict[str, int]:
        """The exit status of each child that ended by itself, badly."""
        return {n: c.returncode for n, c in self.children.items() if n not in self.ended and c.returncode}

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        for name, child in self.children.items():
            if child.poll() is None:
                self.ended.add(name)
                child.terminate()
        for child in self.children.values():
            try:
                child.wait(5)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        for relay in self.relays:  # the children's last lines
            relay.join(5)


def _relay(pipe: IO[bytes], stream: str) -> None:
    """Write each line of a child's output to this process's stream (sys.stdout or sys.stderr, as it
    is when the line comes: a live display's proxy while one runs), until the child closes it."""
    with pipe:
        for line in iter(pipe.readline, b""):
            out = getattr(sys, stream)
            out.write(line.decode(errors="replace"))
            out.flush()
