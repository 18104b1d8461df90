"""Worker containers on Docker engines, through the Docker SDK: `tsf workers up / down / ls`.

Each container runs `tsf worker` from the project's image (Dockerfile), a client of the router the
coordinator meets it at, on the host's network (zenoh needs no published ports then). Containers
carry labels: `tsf.role=worker` and `tsf.sweep=<sweep>`, so `down` and `ls` find them on every
engine named, and nothing else is touched. Images are never pulled unless asked: a missing image
is one line naming the command that builds it.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

from shared.errors import Failure

ROLE, SWEEP = "tsf.role", "tsf.sweep"
IMAGE = "tsf:local"  # compose.yaml's default image name
BUILD = (
    "docker build -t {image} .  (offline: docker/base-image, docker/wheelhouse, then compose.yaml's build)"
)


@dataclass(frozen=True)
class Worker:
    host: str
    name: str
    sweep: str
    status: str


def _client(host: str):  # noqa: ANN202 - a docker.DockerClient (imported here: only these commands need it)
    import docker

    try:
        if host == "local":
            client = docker.from_env()
        else:  # ssh:// through the system's ssh client (no paramiko), tcp:// directly
            client = docker.DockerClient(base_url=host, use_ssh_client=host.startswith("ssh://"))
        client.ping()
    except docker.errors.DockerException as error:
        raise Failure(f"cannot reach the Docker engine {host}: {error}") from None
    return client


def up(
    count: int,
    connect: str,
    sweep: str,
    hosts: list[str],
    image: str = IMAGE,
    slots: int = 1,
    pull: bool = False,
) -> list[Worker]:
    """Start `count` worker containers, spread round-robin over `hosts` ("local": this machine's
    engine; or tcp:// and ssh:// URLs), each a client of the router at `connect`."""
    import docker

    clients = {host: _client(host) for host in hosts}
    for host, client in clients.items():
        try:
            client.images.get(image)
        except docker.errors.ImageNotFound:
            if not pull:
                raise Failure(
                    f"no image {image} on {host}: build it with `{BUILD.format(image=image)}`"
                ) from None
            client.images.pull(image)
    started, batch = [], uuid.uuid4().hex[:6]
    for i in range(count):
        host = hosts[i % len(hosts)]
        name = f"tsf-{sweep}-{batch}-{i}"
        command = ["tsf", "worker", "--sweep", sweep, "--id", name, "--slots", str(slots)]
        command += ["--mode", "client", "--connect", connect]
        clients[host].containers.run(
            image, command, name=name, detach=True, network_mode="host", labels={ROLE: "worker", SWEEP: sweep}
        )
        started.append(Worker(host, name, sweep, "running"))
    return started


def ls(hosts: list[str], sweep: str | None = None) -> list[Worker]:
    """Every worker container on `hosts` (of one sweep, if given), running or ended."""
    labels = [f"{ROLE}=worker", *([f"{SWEEP}={sweep}"] if sweep else [])]
    return [
        Worker(host, c.name, c.labels.get(SWEEP, ""), c.status)
        for host in hosts
        for c in _client(host).containers.list(all=True, filters={"label": labels})
    ]


def down(hosts: list[str], sweep: str | None = None) -> list[Worker]:
    """Stop and remove the worker containers on `hosts` (of one sweep, if given)."""
    gone = []
    for host in hosts:
        labels = [f"{ROLE}=worker", *([f"{SWEEP}={sweep}"] if sweep else [])]
        for c in _client(host).containers.list(all=True, filters={"label": labels}):
            c.remove(force=True)
            gone.append(Worker(host, c.name, c.labels.get(SWEEP, ""), "removed"))
    return gone
