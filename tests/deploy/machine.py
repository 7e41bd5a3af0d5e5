"""The machinery of the deployment tests: what this machine can do, cached Debian trees, dockerd, nspawn.

Everything here runs real tools as root: ``debootstrap`` builds Debian bookworm trees (cached between
runs under :data:`CACHE`, keyed by the exact debootstrap command), ``dockerd`` runs with its own data
root, socket and no iptables, and ``systemd-nspawn`` boots a tree as a throw-away machine on an overlay
(the cached tree is never written). Each piece is a context manager that leaves nothing running.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

CACHE = Path(os.environ.get("MAVATTITUDE_CI_CACHE", "/var/cache/mavattitude-ci"))
SUITE = "bookworm"
# The apt packages the deployment tests need on the host (what .ci/prepare installs).
HOST_PACKAGES = {"dockerd": "docker.io", "debootstrap": "debootstrap", "systemd-nspawn": "systemd-container"}
MIN_FREE_BYTES = 3 * 1024**3  # two trees (~0.5 GB) and the Docker data root (~1 GB), with room to spare
# The client of Debian's docker.io, which has BuildKit built in (a newer client elsewhere on PATH, such as
# one in /usr/local/bin, may need the buildx plugin, which Debian 12 does not package).
DOCKER = "/usr/bin/docker"
LOCK = Path("/run/lock/mavattitude-ci.lock")  # whatever the cache: two dockerds would share a bridge
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
DEBOOTSTRAP_TIMEOUT_S = 900.0  # ~1 min each when the mirror is quick; a slow mirror gets room


@dataclass(frozen=True)
class Tree:
    """A debootstrap tree: its name and the packages it includes.

    Once built, the host's CA bundle is copied in (pip inside then trusts what the host trusts), and
    ``remove`` is deleted: for the Docker base, Debian's EXTERNALLY-MANAGED marker, which the official
    python images do not have.
    """

    name: str
    variant: str | None
    include: tuple[str, ...]
    remove: tuple[str, ...] = ()

    def command(self, target: Path) -> list[str]:
        variant = [f"--variant={self.variant}"] if self.variant else []
        return ["debootstrap", *variant, f"--include={','.join(self.include)}", SUITE, str(target)]

    @property
    def key(self) -> str:
        recipe = [*self.command(Path("-")), "remove", *self.remove, "host CA bundle"]
        return hashlib.sha256(" ".join(recipe).encode()).hexdigest()[:12]

    def finish(self, root: Path) -> None:
        run(["chroot", root, "apt-get", "clean"])
        shutil.copy2(HOST_CA_BUNDLE, root / HOST_CA_BUNDLE.relative_to("/"))
        for path in self.remove:
            (root / path).unlink()


# One Debian 12 tree for both: systemd as PID 1 and sudo, what the README's systemd section assumes, and
# python3 with venv and pip, what python:3.11-slim-bookworm gives the Dockerfile (minbase: one
# debootstrap of about a minute instead of two).
TREE = Tree(
    "debian",
    "minbase",
    (
        "systemd",
        "systemd-sysv",
        "dbus",
        "sudo",
        "python3",
        "python3-venv",
        "python3-pip",
        "python-is-python3",
        "ca-certificates",
    ),
    remove=("usr/lib/python3.11/EXTERNALLY-MANAGED",),
)


def why_not() -> str | None:
    """Why the deployment tests cannot run here, or None when they can."""
    if os.geteuid() != 0:
        return "not root: Docker and systemd-nspawn need root"
    missing = sorted(pkg for tool, pkg in HOST_PACKAGES.items() if shutil.which(tool) is None)
    if missing:
        return f"missing {', '.join(missing)}: `apt-get install {' '.join(missing)}` (.ci/prepare does)"
    CACHE.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(CACHE).free
    if free < MIN_FREE_BYTES:
        return f"only {free / 1024**3:.1f} GB free under {CACHE}, {MIN_FREE_BYTES / 1024**3:.0f} GB needed"
    return None


@contextlib.contextmanager
def cache_lock() -> Iterator[None]:
    """One deployment run at a time on this machine: they share the cache, dockerd's socket and its bridge."""
    with open(LOCK, "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield


def run(
    cmd: Sequence[str | Path], timeout_s: float = 120.0, check: bool = True, **kwargs
) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(
        [str(c) for c in cmd], capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL, **kwargs
    )
    if check and result.returncode != 0:
        raise AssertionError(f"{' '.join(map(str, cmd))} exited {result.returncode}:\n{result.stdout}\n{result.stderr}")
    return result


def terminate(proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    """SIGTERM, and SIGKILL to its whole process group (its own session) if it has not exited in time."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=timeout_s)


def cached_tree(tree: Tree) -> Path:
    """The tree, from the cache or built now (into a temporary name, renamed when complete)."""
    done = CACHE / "trees" / f"{tree.name}-{SUITE}-{tree.key}"
    if done.is_dir():
        return done
    partial = done.with_name(done.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    run(tree.command(partial), timeout_s=DEBOOTSTRAP_TIMEOUT_S)
    tree.finish(partial)
    partial.rename(done)
    for stale in done.parent.iterdir():  # an older recipe's tree
        if stale != done:
            shutil.rmtree(stale, ignore_errors=True)
    return done


class Dockerd:
    """``with Dockerd() as docker:`` — a Docker engine of our own, stopped (with its containers) on exit.

    Its data root is cached under :data:`CACHE` (the base image and the build's layer cache survive
    between runs); its socket, exec root and pid file are its own, so it never meets a system dockerd.
    ``--iptables=false``: the tests reach published ports through docker-proxy on 127.0.0.1.
    """

    START_TIMEOUT_S = 30.0
    STOP_TIMEOUT_S = 20.0

    def __init__(self) -> None:
        self.run_dir = Path("/run/mavattitude-ci")
        self.socket = self.run_dir / "docker.sock"
        self.env = {**os.environ, "DOCKER_HOST": f"unix://{self.socket}", "DOCKER_BUILDKIT": "1"}
        self.env.pop("DOCKER_CONTEXT", None)
        self.proc: subprocess.Popen[bytes] | None = None
        self.log = self.run_dir / "dockerd.log"

    def __enter__(self) -> Dockerd:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [
                    "dockerd",
                    f"--data-root={CACHE / 'docker'}",
                    f"--exec-root={self.run_dir / 'exec'}",
                    f"--pidfile={self.run_dir / 'dockerd.pid'}",
                    f"--host=unix://{self.socket}",
                    "--iptables=false",
                ],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + self.START_TIMEOUT_S
        while self.docker("version", check=False).returncode != 0:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self._stop()
                raise AssertionError(f"dockerd did not start:\n{self.log.read_text()[-3000:]}")
            time.sleep(0.2)  # polling the daemon's socket: there is no event to wait on
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop()

    def _stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            running = self.docker("ps", "-q", check=False).stdout.split()
            if running:
                self.docker("rm", "-f", *running, check=False)
            terminate(self.proc, self.STOP_TIMEOUT_S)  # dockerd stops its containerd with it
        self.proc = None

    def docker(
        self, *args: str | Path, timeout_s: float = 120.0, check: bool = True
    ) -> subprocess.CompletedProcess[str]:
        return run([DOCKER, *args], timeout_s=timeout_s, check=check, env=self.env)

    def has_image(self, name: str) -> bool:
        return self.docker("image", "inspect", name, check=False).returncode == 0

    def import_tree(self, root: Path, name: str) -> None:
        """``tar -C root -c . | docker import - name``: a base image with no registry."""
        with subprocess.Popen(["tar", "-C", str(root), "-c", "."], stdout=subprocess.PIPE) as tar:
            result = subprocess.run(
                [DOCKER, "import", "-", name],
                stdin=tar.stdout,
                capture_output=True,
                text=True,
                env=self.env,
                timeout=300,
            )
        assert tar.returncode == 0 and result.returncode == 0, result.stderr


class NspawnMachine:
    """``with NspawnMachine(tree) as m:`` — the tree booted with systemd as PID 1, on a throw-away overlay.

    This host does not run systemd itself, hence ``--register=no --keep-unit``; the machine shares the
    host's network, so the fake vehicle in the test process talks to the service on 127.0.0.1.
    Commands run inside with ``nsenter`` into all of PID 1's namespaces.
    """

    BOOT_TIMEOUT_S = 60.0
    STOP_TIMEOUT_S = 30.0

    def __init__(self, lower: Path, workdir: Path) -> None:
        self.lower = lower
        self.workdir = workdir
        self.root = workdir / "root"
        self.proc: subprocess.Popen[bytes] | None = None
        self.leader: int | None = None
        self.log = workdir / "console.log"

    def __enter__(self) -> NspawnMachine:
        for part in ("upper", "work", "root"):
            (self.workdir / part).mkdir(parents=True, exist_ok=True)
        layers = f"lowerdir={self.lower},upperdir={self.workdir / 'upper'},workdir={self.workdir / 'work'}"
        run(["mount", "-t", "overlay", "overlay", "-o", layers, self.root])
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [
                    "systemd-nspawn",
                    "-D",
                    self.root,
                    "-b",
                    "--register=no",
                    "--keep-unit",
                    "--console=passive",
                ],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        try:
            self._wait_for_boot()
        except BaseException:
            self._stop()
            raise
        return self

    def _wait_for_boot(self) -> None:
        assert self.proc is not None
        deadline = time.monotonic() + self.BOOT_TIMEOUT_S
        state = "no PID 1 found"
        while True:  # polling: systemd in the machine has no way to tell the host it is up
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the machine did not boot ({state}):\n{self._boot_report()}")
            if self.leader is not None and not Path(f"/proc/{self.leader}").exists():
                # nspawn's outer child, which forks PID 1 and exits: found before it exited, on a busy machine
                self.leader = None
            if self.leader is None:
                children = run(["pgrep", "-P", str(self.proc.pid)], check=False).stdout.split()
                self.leader = int(children[0]) if children else None
            if self.leader is not None:
                done = self.sh("systemctl is-system-running", check=False)
                state = (done.stdout.strip() or done.stderr.strip())[-300:]
                if state in ("running", "degraded"):
                    return
            time.sleep(0.2)

    def _boot_report(self) -> str:
        """What the machine was still doing (its jobs), or why it could not be asked, and nspawn's log."""
        jobs = "no PID 1 to ask"
        if self.leader is not None and self.proc is not None and self.proc.poll() is None:
            done = self.sh("systemctl list-jobs --no-pager", timeout_s=10.0, check=False)
            jobs = (done.stdout + done.stderr)[-2000:]
        return f"jobs: {jobs}\nnspawn (exit {self.proc.poll() if self.proc else None}):\n{self.log.read_text()[-2000:]}"

    def __exit__(self, *exc: object) -> None:
        self._stop()

    def _stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            terminate(self.proc, self.STOP_TIMEOUT_S)  # nspawn asks systemd in the machine to power off
        self.proc = None
        run(["umount", self.root], check=False)

    def sh(self, script: str, timeout_s: float = 120.0, check: bool = True) -> subprocess.CompletedProcess[str]:
        """``script`` run by sh inside the machine as root."""
        assert self.leader is not None
        env = {
            "PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
            "HOME": "/root",
            "LANG": "C.UTF-8",
        }
        cmd = ["nsenter", "-t", str(self.leader), "-a", "sh", "-c", script]
        return run(cmd, timeout_s=timeout_s, check=check, env=env)
