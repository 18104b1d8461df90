"""How long Ctrl-C takes to end `tsf study` while a trial's match is being set up.

A real `tsf study` process of one long trial; a participant consents, and the server starts the
trial's match (its processes, the server's session to its sim, the wait for every process). At
each `--delays` second after the participant's id arrives, SIGINT goes to the server; printed is
the time until the process has exited, and its exit status (goal: 0, within a second or two; it
took a minute, and at times for ever, before the server's waits woke for signals).

    nice .venv/bin/python bench/study_stop.py [--delays 0 0.5 1 2 3 5] [--runs 2]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import websockets

STUDY = (
    'name = "stop"\ntrials = 1\ntrial_seconds = 600\n[[variants]]\nname = "s"\nbait = "B5"\nshooter = "S5"\n'
)


def stopped_after(delay: float, directory: Path) -> tuple[float, int | None]:
    """(seconds from SIGINT to the server's exit, its exit status; None if still running at 90 s)."""
    config = directory / "stop.toml"
    config.write_text(STUDY)
    command = [
        sys.executable,
        "-m",
        "services.commands",
        "study",
        str(config),
        "--out",
        str(directory),
        "--port",
        "0",
    ]
    log = (directory / "server.log").open("w")
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log, text=True, start_new_session=True)
    try:
        line = ""
        while "http" not in line:
            line = server.stdout.readline()
            if not line:
                raise SystemExit("the server printed no address")
        socket = line[line.index("http") :].split()[0].replace("http", "ws", 1) + "ws"

        async def consent_then_stop() -> float:
            async with websockets.connect(socket) as ws:
                await ws.send(json.dumps({"type": "hello"}))
                while json.loads(await ws.recv())["type"] != "participant":
                    await ws.send(json.dumps({"type": "consent"}))
                await asyncio.sleep(delay)  # the trial's match is starting
                sent = time.monotonic()
                server.send_signal(signal.SIGINT)
                await asyncio.to_thread(server.wait, 90)
                return time.monotonic() - sent

        try:
            return asyncio.run(consent_then_stop()), server.returncode
        except subprocess.TimeoutExpired:
            return 90.0, None
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
        log.close()
        if server.returncode:  # what it said last
            print("".join((directory / "server.log").read_text().splitlines(keepends=True)[-15:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--delays", type=float, nargs="+", default=[0, 0.5, 1, 2, 3, 5])
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}")
    for run in range(args.runs):
        for delay in args.delays:
            with tempfile.TemporaryDirectory() as directory:
                seconds, status = stopped_after(delay, Path(directory))
            print(
                f"run {run + 1}, SIGINT {delay:g} s into set-up: exit after {seconds:.2f} s, status {status}"
            )


if __name__ == "__main__":
    main()
