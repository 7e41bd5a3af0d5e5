"""The image built and run as the README's "In Docker" section says, against the fake vehicle.

dockerd runs with its own data root (cached: the base image and the layer cache survive between runs).
The machines have no registry, so the base image is Debian 12's python3.11 made with debootstrap and
passed as ``PYTHON_IMAGE``; everything else is the README's lines, with the host port left to Docker.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from . import machine
from .conftest import EXAMPLE_CONFIG, OUTPUT_TIMEOUT_S, ROOT, assert_attitudes_scored, readme_block, vehicle

BASE_REPOSITORY = "local/python"
README_PORT = "-p 14551:14551/udp"
EPHEMERAL_PORT = "-p 127.0.0.1::14551/udp"  # Docker picks the host port: nothing fixed on the machine
README_CONFIG_DIR = "-v /etc/mavattitude:"
STOP_LIMIT_S = 2.0
HEALTH_TIMEOUT_S = 30.0  # healthy: first check 2 s after start; unhealthy: 5 s stale + 2 failed checks 2 s apart
DIALOUT_GID = 20  # Debian's

pytestmark = pytest.mark.deploy


def _readme_line(prefix: str) -> str:
    lines = [line for line in readme_block("### 3. In Docker") if line.startswith(prefix)]
    assert len(lines) == 1, f"README's Docker section: one `{prefix}` line expected, found {lines}"
    return lines[0]


@pytest.fixture(scope="module")
def docker(deploy_host: None) -> Iterator[machine.Dockerd]:
    with machine.Dockerd() as d:
        yield d


@pytest.fixture(scope="module")
def image(docker: machine.Dockerd) -> str:
    """The README's `docker build` line, run in the checkout against the local base image."""
    base = f"{BASE_REPOSITORY}:3.11-{machine.TREE.key}"  # a new tree recipe, a new base image
    if not docker.has_image(base):
        stale = docker.docker("images", "-q", BASE_REPOSITORY).stdout.split()
        if stale:
            docker.docker("rmi", "-f", *stale)
        docker.import_tree(machine.cached_tree(machine.TREE), base)
    build = _readme_line("DOCKER_BUILDKIT=1 docker build").split()
    assert build[:3] == ["DOCKER_BUILDKIT=1", "docker", "build"] and build[-1] == "."
    tag = build[build.index("-t") + 1]
    args = [*build[2:-1], "--network=host", "--build-arg", f"PYTHON_IMAGE={base}", str(ROOT)]
    docker.docker(*args, timeout_s=900)
    return tag


@pytest.fixture
def container(docker: machine.Dockerd, image: str, tmp_path: Path) -> Iterator[str]:
    """The README's `docker run` line, with a temporary config directory and an ephemeral host port."""
    config_dir = tmp_path / "etc-mavattitude"
    config_dir.mkdir()
    shutil.copy(EXAMPLE_CONFIG, config_dir / "config.yaml")  # the README's `install -m 0644` of it
    (config_dir / "config.yaml").chmod(0o644)
    line = _readme_line("docker run")
    assert README_PORT in line and README_CONFIG_DIR in line, line
    argv = line.replace(README_PORT, EPHEMERAL_PORT).replace(README_CONFIG_DIR, f"-v {config_dir}:").split()
    assert argv[:3] == ["docker", "run", "-d"] and argv[-1] == image
    name = argv[argv.index("--name") + 1]
    docker.docker("rm", "-f", name, check=False)  # one left by an interrupted run
    docker.docker(*argv[1:])
    try:
        yield name
    finally:
        docker.docker("rm", "-f", name, check=False)


def _inspect(docker: machine.Dockerd, name: str, template: str) -> str:
    return docker.docker("inspect", "-f", template, name).stdout.strip()


def _host_port(docker: machine.Dockerd, name: str) -> int:
    mapping = docker.docker("port", name, "14551/udp").stdout.split()[0]  # 127.0.0.1:NNNNN
    return int(mapping.rsplit(":", 1)[1])


def _wait_health(docker: machine.Dockerd, name: str, wanted: str) -> float:
    """Seconds until `docker inspect` reports ``wanted`` (polling: Docker has no event stream we can wait on here)."""
    start = time.monotonic()
    while (status := _inspect(docker, name, "{{.State.Health.Status}}")) != wanted:
        if time.monotonic() - start > HEALTH_TIMEOUT_S:
            log = docker.docker("logs", "--tail", "30", name, check=False)
            pytest.fail(f"health stayed {status!r}, never {wanted!r}; log:\n{log.stdout}{log.stderr}")
        time.sleep(0.5)
    return time.monotonic() - start


def test_image_runs_as_the_readme_says_against_the_fake_vehicle(docker: machine.Dockerd, container: str) -> None:
    port = _host_port(docker, container)
    with vehicle(f"udpout:127.0.0.1:{port}") as v:  # the router's side: it sends to the published port
        if not v.wait_for_outputs(1, OUTPUT_TIMEOUT_S):
            pytest.fail("no ATTITUDE_QUATERNION from the container; log:\n" + docker.docker("logs", container).stderr)
        assert_attitudes_scored(v)
    # Not root, and in dialout (so a --device serial port opens): the process's own credentials.
    pid = _inspect(docker, container, "{{.State.Pid}}")
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines())
    assert status["Uid"].split()[:2] == ["10001", "10001"], status["Uid"]
    assert str(DIALOUT_GID) in status["Groups"].split(), status["Groups"]
    assert _inspect(docker, container, "{{.HostConfig.RestartPolicy.Name}}") == "unless-stopped"
    start = time.monotonic()
    docker.docker("stop", container)
    stopped_s = time.monotonic() - start
    assert _inspect(docker, container, "{{.State.ExitCode}}") == "0"
    assert stopped_s < STOP_LIMIT_S, f"docker stop took {stopped_s:.1f} s"


def test_healthcheck_reports_healthy_then_unhealthy_when_the_loop_is_frozen(
    docker: machine.Dockerd, container: str
) -> None:
    _wait_health(docker, container, "healthy")  # no vehicle needed: the loop runs and waits for one
    docker.docker("kill", "--signal=STOP", container)
    try:
        _wait_health(docker, container, "unhealthy")
    finally:
        docker.docker("kill", "--signal=CONT", container)
    _wait_health(docker, container, "healthy")  # and back once the loop runs again
