"""The command line as a user types it: global flags on either side of the command, suggestions for
mistyped flags, choices and commands, and exit 130 when interrupted."""

from __future__ import annotations

import logging
import signal
from pathlib import Path

import pytest

from mavattitude.cli import EXIT_INTERRUPTED, EXIT_USER_ERROR, main
from mavattitude.commands import about, configure_logging
from tests.commands.process import cli_process


@pytest.fixture
def unopenable(tmp_path: Path) -> Path:
    # A serial device that does not exist: `run` sets the log level, then fails at once with exit 2.
    path = tmp_path / "config.yaml"
    path.write_text('link:\n  connect: "/nonexistent/ttyX,57600"\nlogging:\n  level: WARNING\n')
    return path


@pytest.mark.parametrize("where", ["before", "after"])
def test_a_global_flag_goes_before_or_after_the_command(unopenable: Path, where: str) -> None:
    flag = ["--log-level", "debug"]
    command = ["run", "--config", str(unopenable)]
    assert main(flag + command if where == "before" else command + flag) == EXIT_USER_ERROR
    assert logging.getLogger().level == logging.DEBUG  # the flag, not the config's WARNING


def test_not_given_after_the_command_it_keeps_what_was_given_before(unopenable: Path) -> None:
    assert main(["--log-level", "ERROR", "run", "--config", str(unopenable)]) == EXIT_USER_ERROR
    assert logging.getLogger().level == logging.ERROR


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ["run", "--conect", "udpin:0.0.0.0:14550"],
            "mavattitude run: error: unrecognized argument --conect; did you mean --connect?",
        ),
        (["run", "--log-levle", "DEBUG"], "unrecognized argument --log-levle; did you mean --log-level?"),
        (["rnu"], "invalid choice: 'rnu' (choose from"),
        (["solve", "x.csv", "-o", "y.csv", "--method", "ing"], "did you mean ign?"),
    ],
)
def test_a_mistyped_flag_choice_or_command_gets_a_suggestion(capsys, argv: list[str], said: str) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert said in err
    if argv[0] == "run":
        assert "usage: mavattitude run" in err  # the command's own usage, not the top level's


def test_a_mistyped_command_is_suggested_the_right_one(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["rnu"])
    assert capsys.readouterr().err.rstrip().endswith("did you mean run?")


def test_an_interrupted_offline_command_exits_130(monkeypatch, tmp_path: Path) -> None:
    def interrupted(_args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr("mavattitude.commands.check_config.run", interrupted)
    assert main(["check-config", str(tmp_path / "x.yaml")]) == EXIT_INTERRUPTED


def test_a_simulation_says_it_waits_and_interrupted_exits_130_with_its_summary() -> None:
    # the time-out bounds the reads below; the lines come within ~4 s
    with cli_process("simulate", "--connect", "udpin:127.0.0.1:0", "--duration", "600", timeout_s=60.0) as proc:
        assert proc.stderr is not None
        first, second = proc.stderr.readline(), proc.stderr.readline()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30.0)
    assert "fake vehicle on udpin:127.0.0.1:" in first  # its real port, not :0
    # Nobody asks for the IMU: after 3 s it says so, rather than look like a hang.
    assert "waiting for a service to ask for the IMU stream on udpin:127.0.0.1:" in second
    assert proc.returncode == EXIT_INTERRUPTED
    assert "IMU messages sent: 0" in out


def test_the_records_of_an_inputs_work_name_it_and_no_others(capsys, monkeypatch) -> None:
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)  # with the timestamp, as on a terminal
    log = logging.getLogger("mavattitude.sensors.magref")
    configure_logging("INFO")
    with about("a.bin"):
        log.info("no GPS position")
        with about("b.tlog"):
            log.info("inner")
        log.warning("after the inner block")
    log.info("outside")
    said = [line.split(" ", 2)[2] for line in capsys.readouterr().err.splitlines()]  # past the timestamp
    assert said == [
        "INFO mavattitude.sensors.magref: a.bin: no GPS position",
        "INFO mavattitude.sensors.magref: b.tlog: inner",
        "WARNING mavattitude.sensors.magref: a.bin: after the inner block",
        "INFO mavattitude.sensors.magref: outside",
    ]
