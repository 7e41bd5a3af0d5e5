"""`mavattitude check-config`: validate, print the effective config and where each set value came from."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mavattitude.cli import main
from mavattitude.config import ENV_VAR, from_dict, load_config
from tests.commands.process import run_cli

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", ["ardupilot", "px4", "adis16405"])
def test_prints_the_effective_config_of_each_example(capsys, monkeypatch, name):
    monkeypatch.delenv(ENV_VAR, raising=False)
    path = CONFIGS / f"{name}.yaml"
    assert main(["check-config", str(path)]) == 0
    out = capsys.readouterr().out
    assert from_dict(yaml.safe_load(out)) == load_config(path, env={})
    # One entry for the one file (it set 34 "set by" lines): how many values, and which are not the defaults.
    entry = out[out.index("# values set by a layer") :].splitlines()[1:]
    assert entry[0].startswith(f"#   {path}: ") and all(line.startswith("#     ") for line in entry[1:])
    assert len(entry) <= 3


def test_the_env_overlay_is_shown_as_the_source(tmp_path, capsys, monkeypatch):
    base = tmp_path / "base.yaml"
    base.write_text("estimator: {method: cgn, max_iterations: 7}\n")
    site = tmp_path / "site.yaml"
    site.write_text("estimator: {method: ml}\n")
    monkeypatch.setenv(ENV_VAR, str(site))
    assert main(["check-config", str(base)]) == 0
    out = capsys.readouterr().out
    effective = yaml.safe_load(out)["estimator"]
    assert (effective["method"], effective["max_iterations"]) == ("ml", 7)
    assert out.replace("\n#     ", " ").endswith(  # entries longer than a line go on indented
        f"#   {base}: 1 value; not the defaults: estimator.max_iterations\n"  # its method is overridden below
        f"#   {ENV_VAR}={site}: 1 value; not the defaults: estimator.method\n"
    )


def test_without_a_file_the_defaults_are_printed(capsys, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert main(["check-config"]) == 0
    out = capsys.readouterr().out
    assert from_dict(yaml.safe_load(out)) == from_dict({})
    assert "# every value is a default" in out


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("estimator: {methd: ign}\n", "estimator.methd: unknown key; did you mean method?"),
        ("mounting: {rotation: YAW_91}\n", "unknown mounting rotation 'YAW_91'"),
    ],
)
def test_an_invalid_file_is_one_line_on_stderr_and_exit_2(tmp_path, capsys, monkeypatch, text, message):
    monkeypatch.delenv(ENV_VAR, raising=False)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    assert main(["check-config", str(bad)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mavattitude check-config: error: ") and message in lines[0]
    assert captured.out == ""


def test_as_a_subprocess(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("filter: {cutoff_hz: 30}\n")
    done = run_cli(["check-config", str(bad)])
    assert done.returncode == 2
    assert "filter.cutoff_hz: must be below half of filter.output_rate_hz (25 Hz)" in done.stderr
    assert "Traceback" not in done.stderr
