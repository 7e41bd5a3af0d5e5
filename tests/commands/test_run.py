"""`mavattitude run`: the log level's precedence (flag > config > default)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from mavattitude.cli import EXIT_USER_ERROR, main


@pytest.fixture
def warning_config(tmp_path: Path) -> Path:
    # A serial device that does not exist: `run` sets the log level, then fails to open the link at once.
    path = tmp_path / "config.yaml"
    path.write_text('link:\n  connect: "/nonexistent/ttyX,57600"\nlogging:\n  level: WARNING\n')
    return path


def test_the_configs_level_applies_without_the_flag(warning_config: Path) -> None:
    assert main(["run", "--config", str(warning_config)]) == EXIT_USER_ERROR
    assert logging.getLogger().level == logging.WARNING


@pytest.mark.parametrize("flag", ["INFO", "DEBUG"])
def test_an_explicit_flag_beats_the_config(warning_config: Path, flag: str) -> None:
    # INFO is also the default when nothing says otherwise: given explicitly, it must still win.
    assert main(["--log-level", flag, "run", "--config", str(warning_config)]) == EXIT_USER_ERROR
    assert logging.getLogger().level == getattr(logging, flag)


def test_a_udp_port_another_instance_holds_is_a_one_line_error(capsys) -> None:
    from mavattitude.link import MavlinkLink

    with MavlinkLink("udpin:127.0.0.1:0", source_system=1) as first:  # e.g. the systemd instance
        port = first.local_address[1]
        assert main(["run", "--connect", f"udpin:127.0.0.1:{port}"]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1 and f"cannot open udpin:127.0.0.1:{port}: Address already in use" in errors[0]
    assert "Traceback" not in err


def test_no_request_says_it_stops_every_stream_request(capsys) -> None:
    """--no-request turns link.request_messages off, and with it every stream the service would ask for."""
    from mavattitude.service import ATTITUDE_MESSAGE, GPS_VELOCITY_MESSAGE, TIME_MESSAGE

    with pytest.raises(SystemExit, match="0"):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    no_request = text[text.index("--no-request ") :].split(" --", 1)[0]
    assert [
        m for m in ("input", "position", TIME_MESSAGE, GPS_VELOCITY_MESSAGE, ATTITUDE_MESSAGE) if m not in no_request
    ] == []
