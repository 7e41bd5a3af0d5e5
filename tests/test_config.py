"""The typed config: every value checked, unknown keys named with a suggestion, precedence of the layers."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from mavattitude.config import ENV_VAR, Config, describe, from_dict, load_config
from mavattitude.errors import ConfigError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
EXAMPLES = sorted(CONFIGS.glob("*.yaml"))


def write(tmp_path: Path, name: str, data: dict) -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_defaults_without_any_layer():
    c = load_config(env={})
    assert c == Config()
    assert (c.estimator.method, c.filter.cutoff_hz, c.filter.output_rate_hz) == ("ign", 10.0, 50.0)
    assert (c.link.component_id, c.input.input_timeout_s, c.output.stats_interval_s) == (191, 0.5, 10.0)


def test_the_three_profiles_have_an_example():
    assert {p.stem for p in EXAMPLES} >= {"ardupilot", "px4", "adis16405"}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_file_loads_and_matches_its_profile(path):
    c = load_config(path, env={})
    assert c.input.profile == path.stem


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_file_comments_every_key_with_its_default(path):
    lines = path.read_text(encoding="utf-8").splitlines()
    for key, _default, _doc in describe():
        leaf = key.rsplit(".", 1)[-1]
        matching = [line for line in lines if re.match(rf"\s*{leaf}:", line)]
        assert matching, f"{path.name}: {key} is not in the example"
        assert all("#" in line and "default" in line.split("#", 1)[1] for line in matching), (
            f"{path.name}: {key} has no comment stating its default"
        )


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"estimator": {"methd": "ign"}}, r"estimator\.methd: unknown key; did you mean method\?"),
        ({"estimater": {}}, r"estimater: unknown key; did you mean estimator\?"),
        ({"link": {"signing": {"keyfile": "k"}}}, r"link\.signing\.keyfile: unknown key; did you mean key_file\?"),
        ({"estimator": {"method": "ing"}}, r"estimator\.method: 'ing' is not one of .*did you mean ign\?"),
        ({"estimator": {"max_iterations": 2.5}}, r"estimator\.max_iterations: expected an integer"),
        ({"estimator": {"max_iterations": 0}}, r"estimator\.max_iterations: 0 is out of range: must be ≥ 1"),
        ({"filter": {"cutoff_hz": "10"}}, r"filter\.cutoff_hz: expected a number, got '10'"),
        ({"filter": {"cutoff_hz": True}}, r"filter\.cutoff_hz: expected a number, got True"),
        ({"filter": {"cutoff_hz": float("nan")}}, r"filter\.cutoff_hz: expected a finite number"),
        ({"input": {"input_timeout_s": 0}}, r"input\.input_timeout_s: 0 is out of range: must be > 0"),
        ({"link": {"vehicle_system_id": 255}}, r"link\.vehicle_system_id: 255 is out of range: must be ≤ 254"),
        ({"link": {"request_messages": "yes"}}, r"link\.request_messages: expected true or false"),
        ({"link": {"component_id": 1}}, r"link\.component_id: 1 is the autopilot's own component id: use 191"),
        ({"link": {"component_id": 0}}, r"link\.component_id: 0 is out of range: must be ≥ 1"),
        ({"noise": {"mag_std_uT": -1}}, r"noise\.mag_std_uT: -1 is out of range: must be > 0"),
        ({"estimator": {"fused": {"mag_std_uT": 0}}}, r"estimator\.fused\.mag_std_uT: 0 is out of range: must be > 0"),
        (
            {"estimator": {"fused": {"update_rate": 25}}},
            r"estimator\.fused\.update_rate: unknown key; did you mean update_rate_hz\?",
        ),
        (
            {"estimator": {"fused": {"gyro_scale_fraction": 0.7}}},
            r"gyro_scale_fraction: 0\.7 is out of range: must be ≤ 0\.5",
        ),
        (
            {"estimator": {"method": "fused"}, "noise": {"mag_std_uT": 0.3}},
            r"noise\.mag_std_uT: not used by estimator\.method fused.*estimator\.fused\.mag_std_uT",
        ),
        ({"noise": {"accel_std_mps2": [1, 2]}}, r"noise\.accel_std_mps2: expected a list of 3 numbers"),
        ({"calibration": {"mag": {"soft_iron": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}}}, r"soft_iron: .*singular"),
        ({"calibration": {"accel": {"bias_mps2": [0, "x", 0]}}}, r"calibration\.accel\.bias_mps2\[1\]: expected"),
        ({"mounting": {"rotation": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}}, r"mounting\.rotation: .*must be a rotation"),
        ({"mounting": {"rotation": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}}, r"mounting\.rotation: .*determinant \+1"),
        ({"reference": {"magnetic": "wmm"}}, r"reference\.magnetic: 'wmm': expected auto"),
        ({"reference": {"magnetic": {"declination_deg": 3}}}, r"reference\.magnetic\.inclination_deg: missing"),
        ({"reference": {"magnetic": {"declination_deg": 3, "inclination_deg": 95}}}, r"inclination_deg: 95 is out"),
        ({"reference": {"magnetic": {"field_ned_uT": [0, 0, 0]}}}, r"field_ned_uT: the field vector is zero"),
        (
            {"reference": {"magnetic": {"field_ned_uT": [20, 0, 40], "declination_deg": 1}}},
            r"reference\.magnetic\.declination_deg: unknown key",
        ),
        ({"link": {"signing": {"require_signing": True}}}, r"require_signing: true needs link\.signing\.key_file"),
        ({"link": {"connect": "udpout:localhost"}}, r"link\.connect: connection string 'udpout:localhost': expected"),
        ({"link": {"connect": "udpin:0.0.0.0:99999"}}, r"link\.connect: .*port 99999 is out of range 0-65535"),
        (
            {"input": {"profile": "adis16405", "message": "SCALED_IMU"}},
            r"input\.message: profile adis16405 reads RAW_IMU",
        ),
        ({"input": {"profile": "px4", "message": "RAW_IMU"}}, r"input\.message: profile px4 reads HIGHRES_IMU"),
        ({"input": {"profile": "custom"}}, r"input\.custom\.accel_mps2_per_lsb: required with profile: custom"),
        ({"input": {"custom": {"mag_uT_per_lsb": 0.1}}}, r"input\.custom: scales are only used with profile"),
        ({"filter": {"cutoff_hz": 25}}, r"filter\.cutoff_hz: must be below half of filter\.output_rate_hz \(25 Hz\)"),
        ({"logging": ["INFO"]}, r"logging: expected a mapping of keys"),
    ],
)
def test_every_bad_value_is_named_by_its_path(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(data)


def test_the_fused_method_takes_noise_rest_s():
    """noise.rest_s is no σ with a counterpart in estimator.fused: it times the rest measurement of the IGN that
    solves a too-slow input per sample under the fused method too, so it is taken, not refused."""
    c = from_dict({"estimator": {"method": "fused"}, "noise": {"rest_s": 0}})
    assert c.noise.rest_s == 0.0


def test_values_are_normalised():
    c = from_dict(
        {
            "input": {"message": "highres_imu", "profile": "PX4"},
            "noise": {"accel_std_mps2": 0.1, "mag_std_uT": [0.2, 0.3, 0.4]},
            "mounting": {"rotation": "yaw_90"},
            "filter": {"enabled": False, "cutoff_hz": 40},  # no resampling: the aliasing rule does not apply
            "reference": {"magnetic": {"declination_deg": 3, "inclination_deg": 60, "intensity_uT": 48}},
        }
    )
    assert (c.input.message, c.input.profile, c.mounting.rotation) == ("HIGHRES_IMU", "px4", "YAW_90")
    assert c.noise.accel_std_mps2 == (0.1, 0.1, 0.1)
    assert c.noise.mag_std_uT == (0.2, 0.3, 0.4)
    m = c.reference.magnetic
    assert (m.mode, m.declination_deg, m.inclination_deg, m.intensity_uT) == ("angles", 3.0, 60.0, 48.0)


def test_effective_config_round_trips_through_yaml():
    c = from_dict(
        {
            "mounting": {"rotation": [[0, -1, 0], [1, 0, 0], [0, 0, 1]]},
            "reference": {"magnetic": {"field_ned_uT": [20, 1, 40]}},
            "input": {
                "profile": "custom",
                "custom": {"accel_mps2_per_lsb": 1, "gyro_radps_per_lsb": 1, "mag_uT_per_lsb": 1},
            },
        }
    )
    assert from_dict(yaml.safe_load(c.to_yaml())) == c


def test_precedence_flags_over_env_file_over_config_file_over_defaults(tmp_path):
    base = write(
        tmp_path,
        "base.yaml",
        {
            "estimator": {"method": "cgn", "max_iterations": 7},
            "filter": {"cutoff_hz": 8},
            "link": {"connect": "tcp:127.0.0.1:5760"},
        },
    )
    site = write(tmp_path, "site.yaml", {"estimator": {"method": "ml"}, "link": {"connect": "udpin:0.0.0.0:14551"}})
    env = {ENV_VAR: str(site)}

    only_file = load_config(base, env={})
    assert (only_file.estimator.method, only_file.estimator.max_iterations) == ("cgn", 7)
    assert only_file.estimator.min_angle_deg == 5.0  # default under the file

    with_env = load_config(base, env=env)
    assert with_env.estimator.method == "ml"  # env file over config file
    assert with_env.estimator.max_iterations == 7  # merged key by key: the file's other keys stay
    assert with_env.link.connect == "udpin:0.0.0.0:14551"
    assert with_env.filter.cutoff_hz == 8.0

    with_flags = load_config(base, overrides={"estimator.method": "triad", "filter.cutoff_hz": 5}, env=env)
    assert (with_flags.estimator.method, with_flags.filter.cutoff_hz) == ("triad", 5.0)  # flags over both
    assert with_flags.link.connect == "udpin:0.0.0.0:14551"

    env_only = load_config(None, env=env)
    assert (env_only.estimator.method, env_only.estimator.max_iterations) == ("ml", 10)


def test_the_process_environment_is_read_by_default(tmp_path, monkeypatch):
    site = write(tmp_path, "site.yaml", {"estimator": {"method": "ml"}})
    monkeypatch.setenv(ENV_VAR, str(site))
    assert load_config().estimator.method == "ml"


def test_a_higher_layer_replaces_the_magnetic_reference_whole(tmp_path):
    base = write(tmp_path, "base.yaml", {"reference": {"magnetic": {"declination_deg": 3, "inclination_deg": 60}}})
    vector = {"reference.magnetic": {"field_ned_uT": [20, 0, 40]}}
    c = load_config(base, overrides=vector, env={})
    assert c.reference.magnetic.mode == "vector"
    assert c.reference.magnetic.field_ned_uT == (20.0, 0.0, 40.0)


@pytest.mark.parametrize("order", [1, -1])
def test_a_flag_giving_a_section_a_value_and_keys_is_refused(order):
    """``--set filter=3 --set filter.cutoff_hz=5``, either way round: one would silently lose the other."""
    flags = dict(list({"filter": {"enabled": False}, "filter.cutoff_hz": 5}.items())[::order])
    with pytest.raises(
        ConfigError, match=r"command-line flags: filter: given a value and also the key filter\.cutoff_hz"
    ):
        load_config(None, overrides=flags, env={})


def test_errors_name_the_layer_they_come_from(tmp_path):
    base = write(tmp_path, "base.yaml", {"estimator": {"method": "ign"}})
    bad = write(tmp_path, "site.yaml", {"estimator": {"tolerence": 1e-9}})
    with pytest.raises(ConfigError, match=rf"{ENV_VAR}=.*site\.yaml:2:3: estimator\.tolerence: unknown key; did you"):
        load_config(base, env={ENV_VAR: str(bad)})  # the file's line:column of the key, as an editor counts
    with pytest.raises(ConfigError, match=r"command-line flags: estimator\.method: 'x' is not one of"):
        load_config(base, overrides={"estimator.method": "x"}, env={})
    with pytest.raises(ConfigError, match=r"effective config: filter\.cutoff_hz: must be below half"):
        load_config(base, overrides={"filter.output_rate_hz": 10}, env={})


def test_merge_keys_are_taken_and_a_key_given_again_overrides_them(tmp_path):
    """YAML's ``<<: *anchor`` (or an inline mapping): its keys are taken, and one the mapping gives itself wins
    (it is not a key given twice); a merged key that is wrong is said where the merged mapping gives it."""
    path = tmp_path / "merged.yaml"
    fitted = "{hard_iron_uT: [5, 0, 0], soft_iron: [[2, 0, 0], [0, 2, 0], [0, 0, 2]]}"
    path.write_text(f"calibration:\n  mag:\n    <<: {fitted}\n    hard_iron_uT: [6, 0, 0]\n", encoding="utf-8")
    mag = load_config(path, env={}).calibration.mag
    assert mag.hard_iron_uT == (6.0, 0.0, 0.0) and mag.soft_iron[0] == (2.0, 0.0, 0.0)
    path.write_text(f"calibration:\n  mag:\n    <<: {fitted.replace('5', 'x')}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"merged\.yaml:3:10: calibration\.mag\.hard_iron_uT"):
        load_config(path, env={})


def test_a_single_layer_is_named_in_cross_key_errors(tmp_path):
    only = write(tmp_path, "only.yaml", {"filter": {"cutoff_hz": 30}})
    with pytest.raises(ConfigError, match=r"only\.yaml: filter\.cutoff_hz: must be below half"):
        load_config(only, env={})


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match=r"missing\.yaml: cannot read config file"):
        load_config(tmp_path / "missing.yaml", env={})
    broken = tmp_path / "broken.yaml"
    broken.write_text("estimator: [unclosed\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"broken\.yaml:2:1: not valid YAML: expected ',' or ']'"):
        load_config(broken, env={})  # where the parser gave up, 1-based line:column as editors count
    twice = tmp_path / "twice.yaml"
    twice.write_text("filter:\n  cutoff_hz: 5\n  enabled: true\n  cutoff_hz: 8\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"twice\.yaml:4:3: not valid YAML: key 'cutoff_hz' given twice"):
        load_config(twice, env={})  # PyYAML alone keeps the last one silently
    complex_key = tmp_path / "complex.yaml"
    complex_key.write_text("? [filter, enabled]\n: false\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"complex\.yaml:1:3: not valid YAML: found unhashable key"):
        load_config(complex_key, env={})
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"filter:\n  \xff\xfe\n")
    with pytest.raises(ConfigError, match=r"binary\.yaml: not a YAML text file \(byte 10 is not UTF-8\)"):
        load_config(binary, env={})
    listing = tmp_path / "list.yaml"
    listing.write_text("- a\n- b\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"list\.yaml: expected a mapping of sections"):
        load_config(listing, env={})
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing but a comment\n", encoding="utf-8")
    assert load_config(empty, env={}) == Config()


def test_yaml_is_loaded_safely(tmp_path):
    evil = tmp_path / "evil.yaml"
    evil.write_text("logging: !!python/object/apply:os.system ['true']\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(evil, env={})


def test_a_bad_value_is_named_by_its_line_and_column(tmp_path):
    path = tmp_path / "site.yaml"
    path.write_text("link:\n  connect: udpin:0.0.0.0:14550\nfilter:\n  enabled: true\n  cutoff_hz: -3\n")
    with pytest.raises(ConfigError, match=r"site\.yaml:5:3: filter\.cutoff_hz: -3 is out of range"):
        load_config(path, env={})
    path.write_text("mounting:\n  rotation: {yaw: 90}\n")  # a key inside a value the file holds: its parent's line
    with pytest.raises(ConfigError, match=r"site\.yaml:2:3: mounting\.rotation"):
        load_config(path, env={})
