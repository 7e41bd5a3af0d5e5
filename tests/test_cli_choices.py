"""Every choice list the command line offers is one of the project's definitions, not a copy of it."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from mavattitude import config
from mavattitude.cli import build_parser
from mavattitude.commands.simulate import scenarios
from mavattitude.estimation import METHODS
from mavattitude.pipeline import ESTIMATORS
from mavattitude.sensors import units
from mavattitude.validation.runner import PATHS

# flag (argparse dest) → the definitions its choices may be: the whole list, or (simulate, calibrate) the
# fixed unit profiles only, since those commands encode or decode without input.custom scales.
DEFINITIONS = {
    "log_level": [config.LOG_LEVELS],
    "method": [METHODS],
    "methods": [METHODS],
    "message": [units.MESSAGES],
    "profile": [units.PROFILE_NAMES, tuple(units.PROFILES)],
    "paths_run": [PATHS],
    "script": [tuple(scenarios.SCRIPTS)],
    "sensors": [tuple(scenarios.SENSORS)],
    "sensor": [("mag",)],  # calibrate: the one sensor it fits
}


def _choice_actions() -> list[tuple[str, argparse.Action]]:
    """(command, action) for every flag or argument with a choice list, the global ones as command ''."""
    parser = build_parser()
    found = [("", a) for a in parser._actions if a.choices and not isinstance(a, argparse._SubParsersAction)]
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in commands.choices.items():
        found += [(name, a) for a in sub._actions if a.choices]
    return found


@pytest.mark.parametrize(("command", "action"), _choice_actions(), ids=lambda x: x if isinstance(x, str) else x.dest)
def test_every_choice_list_is_a_definition(command, action):
    assert action.dest in DEFINITIONS, f"{command} --{action.dest}: choices with no known definition"
    assert {tuple(sorted(d)) for d in DEFINITIONS[action.dest]} >= {tuple(sorted(action.choices))}


def test_the_config_checks_the_same_lists():
    checks = {f"{s.name}.{f.name}": f.metadata for s in dataclasses.fields(config.Config) for f in _fields(s)}
    for key, values, bad in [
        ("input.message", units.MESSAGES, "RAW_IMU9"),
        ("input.profile", units.PROFILE_NAMES, "betaflight"),
        ("estimator.method", METHODS, "quest"),
        ("logging.level", config.LOG_LEVELS, "TRACE"),
    ]:
        check = checks[key]["check"]
        assert [check(v, key) for v in values] == list(values)
        with pytest.raises(config.ConfigError, match=f"{key}: '{bad}' is not one of {', '.join(values)}"):
            check(bad, key)


def _fields(section: dataclasses.Field) -> tuple[dataclasses.Field, ...]:
    return dataclasses.fields(section.default_factory) if section.default_factory is not dataclasses.MISSING else ()


def test_every_method_has_an_estimator():
    assert tuple(ESTIMATORS) == tuple(METHODS)
