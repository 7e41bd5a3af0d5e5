"""The typed, validated configuration: one YAML schema for the service, `solve`, `replay` and validation.

Every section is a frozen dataclass; every value is checked once, here, for type and range, and an
unknown key is an error naming its full path with the nearest known key
(``estimator.methd: unknown key; did you mean method?``).

Precedence (highest first), each layer overriding the one below key by key:

1. command-line flags (``overrides``), e.g. ``--method cgn``;
2. the file named by the ``MAVATTITUDE_CONFIG`` environment variable (an overlay: a site-specific file
   that changes a few keys of the main one, such as ``link.connect`` or the signing key);
3. the config file given on the command line (``--config FILE`` / ``check-config FILE``);
4. the defaults written in this module (and in ``configs/*.yaml``).

Mappings merge key by key across layers; a scalar or a list replaces the value below it. The two
polymorphic values, ``reference.magnetic`` and ``mounting.rotation``, are always replaced whole, so a
higher layer can switch e.g. from angles to a field vector without leftovers.

Units are in the key names (``_mps2``, ``_uT``, ``_radps``, ``_hz``, ``_s``, ``_deg``).
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import math
import os
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mavattitude.endpoints import parse_connect
from mavattitude.errors import ConfigError, LinkError
from mavattitude.estimation import METHODS, SNAPSHOT_METHODS
from mavattitude.estimation.compass import CompassSettings
from mavattitude.estimation.conventions import Mat3, Vec3
from mavattitude.estimation.crosscheck import CrossCheckSettings
from mavattitude.estimation.fused.settings import FusedSettings
from mavattitude.estimation.solve import DEFAULT_METHOD, MAX_ITERATIONS, MIN_ANGLE_DEG, TOLERANCE_RAD
from mavattitude.sensors.calibration import Calibration, MagCalibration
from mavattitude.sensors.frontend import FrontEndSettings
from mavattitude.sensors.magref import MagneticReference
from mavattitude.sensors.mounting import mounting_matrix
from mavattitude.sensors.units import MESSAGES, PROFILE_NAMES, PROFILES, CustomScales

ENV_VAR = "MAVATTITUDE_CONFIG"

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
# Paths whose value is replaced whole by a higher layer (polymorphic: a string or a mapping/matrix).
REPLACE_WHOLE = frozenset({"reference.magnetic", "mounting.rotation"})

Check = Callable[[Any, str], Any]


# --- value checks: each takes the raw YAML value and its dotted path, returns the typed value -----------


def _fail(path: str, why: str) -> typing.NoReturn:
    raise ConfigError(f"{path}: {why}")


def _number(lo: float | None = None, hi: float | None = None, *, integer: bool = False, lo_open: bool = False) -> Check:
    """A finite number in [lo, hi] (or (lo, hi] with ``lo_open``); ``integer`` refuses fractions."""

    def check(value: Any, path: str) -> float | int:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            _fail(path, f"expected a number, got {value!r}")
        if integer and not (isinstance(value, int) or float(value).is_integer()):
            _fail(path, f"expected an integer, got {value!r}")
        if not math.isfinite(value):
            _fail(path, f"expected a finite number, got {value!r}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            _fail(path, f"{value!r} is out of range: must be {'>' if lo_open else '≥'} {lo}")
        if hi is not None and value > hi:
            _fail(path, f"{value!r} is out of range: must be ≤ {hi}")
        return int(value) if integer else float(value)

    return check


_positive = _number(0.0, lo_open=True)  # a scale, a σ, a frequency: > 0


def _choice(*options: str, fold: Callable[[str], str] = str.lower) -> Check:
    def check(value: Any, path: str) -> str:
        if isinstance(value, str) and fold(value) in options:
            return fold(value)
        close = difflib.get_close_matches(str(value), options, n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        _fail(path, f"{value!r} is not one of {', '.join(options)}{hint}")

    return check


def _boolean(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        _fail(path, f"expected true or false, got {value!r}")
    return value


def _text(value: Any, path: str) -> str:
    if not isinstance(value, str) or not value.strip():
        _fail(path, f"expected a non-empty string, got {value!r}")
    return value


def _connection(value: Any, path: str) -> str:
    """A connection string :func:`~mavattitude.endpoints.parse_connect` takes."""
    try:
        parse_connect(_text(value, path))
    except LinkError as exc:
        _fail(path, str(exc))
    return value


AUTOPILOT_COMPONENT_ID = 1  # MAV_COMP_ID_AUTOPILOT1


def _component_id(value: Any, path: str) -> int:
    """Our MAVLink component id: 1–255, not the autopilot's (a ground station would take our messages for the
    autopilot's, and we its HEARTBEAT for a second program under our id)."""
    component = int(_number(1, 255, integer=True)(value, path))
    if component == AUTOPILOT_COMPONENT_ID:
        _fail(path, "1 is the autopilot's own component id: use 191 (an onboard computer) or another free id")
    return component


def _optional(check: Check) -> Check:
    return lambda value, path: None if value is None else check(value, path)


def _vec3(value: Any, path: str, element: Check | None = None) -> Vec3:
    element = element or _number()
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        _fail(path, f"expected a list of 3 numbers, got {value!r}")
    return tuple(element(v, f"{path}[{i}]") for i, v in enumerate(value))  # type: ignore[return-value]


def _mat3(value: Any, path: str) -> Mat3:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        _fail(path, f"expected a 3×3 matrix (a list of 3 rows of 3 numbers), got {value!r}")
    m = tuple(_vec3(row, f"{path}[{i}]") for i, row in enumerate(value))
    if abs(_det(m)) < 1e-6:
        _fail(path, "the matrix is singular (determinant ≈ 0)")
    return m  # type: ignore[return-value]


def _per_axis_std(value: Any, path: str) -> Vec3:
    """A noise σ: one positive value for all three axes, or three."""
    if isinstance(value, (list, tuple)):
        return _vec3(value, path, _positive)
    s = _positive(value, path)
    return (s, s, s)


def _rotation(value: Any, path: str) -> str | Mat3:
    """A mounting rotation: an ArduPilot-style name (checked by the front end) or a proper rotation matrix."""
    if isinstance(value, str):
        return _text(value, path).upper()
    m = _mat3(value, path)
    try:
        mounting_matrix(m)  # the front end's rule: a proper rotation
    except ConfigError as exc:
        _fail(path, str(exc))
    return m


def _det(m: Any) -> float:
    return (
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    )


def _meta(check: Check, doc: str) -> dict[str, Any]:
    """A field's check and one-line description (shown by ``describe``)."""
    return {"check": check, "doc": doc}


# --- the schema (defaults are the domain settings' own where there are some) ---------------------------------


_FRONT_END = FrontEndSettings()


@dataclass(frozen=True)
class SigningConfig:
    key_file: str | None = field(
        default=None, metadata=_meta(_optional(_text), "MAVLink 2 signing key: 32 raw bytes or a passphrase")
    )
    require_signing: bool = field(default=False, metadata=_meta(_boolean, "reject unsigned or badly signed input"))


@dataclass(frozen=True)
class LinkConfig:
    connect: str = field(
        default="udpin:0.0.0.0:14551",
        metadata=_meta(_connection, "pymavlink connection string (udpin:, udpout:, tcp:, serial)"),
    )
    vehicle_system_id: int = field(
        default=0, metadata=_meta(_number(0, 254, integer=True), "autopilot system id; 0 = first autopilot")
    )
    component_id: int = field(
        default=191, metadata=_meta(_component_id, "our component id (191 = onboard computer; not the autopilot's 1)")
    )
    request_messages: bool = field(
        default=True,
        metadata=_meta(
            _boolean,
            "ask with SET_MESSAGE_INTERVAL for the input and the streams the config uses (position, GPS, ATTITUDE)",
        ),
    )
    request_rate_hz: float = field(
        default=200.0, metadata=_meta(_number(0.0, 2000.0, lo_open=True), "requested input rate, Hz")
    )
    request_repeat_s: float = field(
        default=5.0, metadata=_meta(_number(0.5, 3600.0), "re-assert the requested rate this often, s")
    )
    signing: SigningConfig = field(default_factory=SigningConfig)


@dataclass(frozen=True)
class InputConfig:
    message: str = field(
        default="RAW_IMU", metadata=_meta(_choice(*MESSAGES, fold=str.upper), "MAVLink IMU message to read")
    )
    profile: str = field(default="ardupilot", metadata=_meta(_choice(*PROFILE_NAMES), "unit profile of that message"))
    input_timeout_s: float = field(
        default=_FRONT_END.input_timeout_s,
        metadata=_meta(_number(0.0, 60.0, lo_open=True), "input gap that stops output, s"),
    )
    custom: CustomScales = field(default_factory=CustomScales)


@dataclass(frozen=True)
class MountingConfig:
    rotation: str | Mat3 = field(
        default=_FRONT_END.mounting, metadata=_meta(_rotation, "board → body rotation: ArduPilot name or 3×3 matrix")
    )
    autopilot_trim: bool = field(
        default=True,
        metadata=_meta(
            _boolean,
            "turn the readings by ArduPilot's level trim (AHRS_TRIM_X/Y, asked of the vehicle or read from the log),"
            " so the attitude is of the vehicle's frame, as the autopilot's",
        ),
    )


@dataclass(frozen=True)
class FilterConfig:
    enabled: bool = field(
        default=_FRONT_END.filter_enabled,
        metadata=_meta(_boolean, "low-pass + resample; false solves every input sample as it comes"),
    )
    cutoff_hz: float = field(
        default=_FRONT_END.cutoff_hz, metadata=_meta(_positive, "Butterworth cutoff, Hz (< output_rate_hz / 2)")
    )
    output_rate_hz: float = field(
        default=_FRONT_END.output_rate_hz,
        metadata=_meta(_number(0.0, 1000.0, lo_open=True), "resampled output rate, Hz"),
    )


@dataclass(frozen=True)
class NoiseConfig:
    accel_std_mps2: Vec3 = field(
        default=(0.05, 0.05, 0.05), metadata=_meta(_per_axis_std, "accelerometer σ per axis, m/s²")
    )
    mag_std_uT: Vec3 = field(default=(0.5, 0.5, 0.5), metadata=_meta(_per_axis_std, "magnetometer σ per axis, µT"))
    rest_s: float = field(
        default=10.0,
        metadata=_meta(
            _number(0.0, 3600.0), "still this long in all, the σ measured at rest replace these, s (0: never)"
        ),
    )


NOISE_SIGMA_KEYS = ("accel_std_mps2", "mag_std_uT")  # the sensor σ (a method with its own σ refuses them)

_ANGLES: dict[str, Check] = {
    "declination_deg": _optional(_number(-180.0, 180.0)),
    "inclination_deg": _optional(_number(-90.0, 90.0)),
    "intensity_uT": _optional(_number(0.0, 1000.0, lo_open=True)),
}


def _magnetic(value: Any, path: str) -> MagneticReference:
    if isinstance(value, str):
        if value.lower() != "auto":
            _fail(path, f"{value!r}: expected auto, {{declination_deg, inclination_deg}} or {{field_ned_uT}}")
        return MagneticReference()
    if not isinstance(value, Mapping):
        _fail(path, f"expected auto or a mapping, got {value!r}")
    if "field_ned_uT" in value:
        _reject_unknown(value, ("field_ned_uT",), path)
        values = {"mode": "vector", "field_ned_uT": _vec3(value["field_ned_uT"], f"{path}.field_ned_uT")}
    else:
        _reject_unknown(value, _ANGLES, path)
        values = {"mode": "angles", **{k: check(value.get(k), f"{path}.{k}") for k, check in _ANGLES.items()}}
    try:
        return MagneticReference(**values)
    except ConfigError as exc:  # it names the key at fault
        raise ConfigError(f"{path}.{exc}") from None


@dataclass(frozen=True)
class ReferenceConfig:
    magnetic: MagneticReference = field(
        default_factory=MagneticReference,
        metadata=_meta(_magnetic, "auto | {declination_deg, inclination_deg[, intensity_uT]} | {field_ned_uT}"),
    )
    position_wait_s: float = field(
        default=5.0,
        metadata=_meta(
            _number(0.0, 600.0),
            "auto: without a GPS position this long after the IMU stream starts (vehicle time), the field is "
            "measured from the compass (heading: magnetic north, or the autopilot's by its COMPASS_DEC or "
            "EKF2_MAG_DECL) until one arrives, s",
        ),
    )


@dataclass(frozen=True)
class EstimatorConfig:
    method: str = field(
        default=DEFAULT_METHOD,
        metadata=_meta(_choice(*METHODS), f"solver: {', '.join(SNAPSHOT_METHODS)}, or fused (gyro-aided)"),
    )
    max_iterations: int = field(
        default=MAX_ITERATIONS, metadata=_meta(_number(1, 100, integer=True), "Gauss–Newton iteration bound")
    )
    tolerance: float = field(
        default=TOLERANCE_RAD,
        metadata=_meta(
            _number(0.0, 1e-3, lo_open=True), "converged when a Gauss–Newton correction is below this angle, rad"
        ),
    )
    min_angle_deg: float = field(
        default=MIN_ANGLE_DEG, metadata=_meta(_number(0.0, 90.0), "refuse acc/mag closer than this to collinear, deg")
    )
    fused: FusedSettings = field(default_factory=FusedSettings)  # the gyro-aided filter (method: fused)


@dataclass(frozen=True)
class OutputConfig:
    stats_interval_s: float = field(
        default=10.0, metadata=_meta(_number(0.0, 86400.0, lo_open=True), "counters log line period, s")
    )
    statustext: bool = field(
        default=True, metadata=_meta(_boolean, "send STATUSTEXT on start, input loss, degenerate geometry")
    )
    statustext_interval_s: float = field(
        default=5.0, metadata=_meta(_number(0.0, 3600.0), "minimum time between repeated STATUSTEXT, s")
    )
    covariance: bool = field(
        default=True,
        metadata=_meta(_boolean, "send ATTITUDE_QUATERNION_COV (rad², body frame) with every attitude"),
    )
    wait_ms: float = field(
        default=0.0,
        metadata=_meta(
            _number(0.0, 20.0),
            "longest an input datagram that completes an output tick waits to be read (UDP on Linux), ms: fewer"
            " wake-ups for more latency",
        ),
    )


@dataclass(frozen=True)
class LoggingConfig:
    level: str = field(default="INFO", metadata=_meta(_choice(*LOG_LEVELS, fold=str.upper), "log level"))


@dataclass(frozen=True)
class Config:
    link: LinkConfig = field(default_factory=LinkConfig)
    input: InputConfig = field(default_factory=InputConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    calibration: Calibration = field(default_factory=Calibration)
    filter: FilterConfig = field(default_factory=FilterConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    compass: CompassSettings = field(default_factory=CompassSettings)
    crosscheck: CrossCheckSettings = field(default_factory=CrossCheckSettings)
    output: OutputConfig = field(default_factory=OutputConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)

    def for_another_compass(self) -> Config:
        """This config for judging a compass other than the one ``calibration.mag`` was fitted to (input.message's,
        the one replayed): without it, as that compass's readings carry the autopilot's own calibration, and the
        hard iron of another would put its dip and |B| off."""
        return dataclasses.replace(self, calibration=dataclasses.replace(self.calibration, mag=MagCalibration()))

    def to_dict(self) -> dict[str, Any]:
        """Plain YAML-ready data (lists, not tuples), the same shape the loader reads."""
        return _to_plain(self)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None)


#: The defaults, for help texts that quote them.
DEFAULTS = Config()


# --- building and cross-checks ----------------------------------------------------------------------------


def _reject_unknown(data: Mapping[str, Any], known: typing.Iterable[str], path: str) -> None:
    known = list(known)
    for key in data:
        if key not in known:
            where = f"{path}.{key}" if path else str(key)
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"; did you mean {close[0]}?" if close else f"; known keys: {', '.join(known)}"
            raise ConfigError(f"{where}: unknown key{hint}")


def _build(cls: type, data: Any, path: str) -> Any:
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        _fail(path or "config", f"expected a mapping of keys, got {data!r}")
    fields = dataclasses.fields(cls)
    _reject_unknown(data, (f.name for f in fields), path)
    hints = typing.get_type_hints(cls)
    values = {}
    for f in fields:
        if f.name not in data:
            continue
        sub = f"{path}.{f.name}" if path else f.name
        check = _check_of(f, hints[f.name])
        values[f.name] = check(data[f.name], sub) if check else _build(hints[f.name], data[f.name], sub)
    return cls(**values)


def _check_of(f: dataclasses.Field, hint: Any) -> Check | None:
    """A key's check: its own (``_meta``), a number range (``range: (lo, hi, lo_open)``, as the settings that
    live beside their code, e.g. :class:`FusedSettings`, give it), or by its type in the domain sections the
    config imports (their fields carry only a description); ``None`` for a nested section."""
    if "range" in f.metadata:
        lo, hi, lo_open = f.metadata["range"]
        check = _number(lo, hi, lo_open=lo_open)
        return _optional(check) if type(None) in typing.get_args(hint) else check
    return f.metadata.get("check") or _CHECK_BY_TYPE.get(hint)


_CHECK_BY_TYPE: dict[Any, Check] = {bool: _boolean, Vec3: _vec3, Mat3: _mat3}


def _cross_check(c: Config) -> None:
    """Rules that span keys."""
    if c.link.signing.require_signing and c.link.signing.key_file is None:
        _fail("link.signing.require_signing", "true needs link.signing.key_file")
    profile = PROFILES.get(c.input.profile)
    if profile is not None and c.input.message not in profile.messages:
        _fail("input.message", f"profile {c.input.profile} reads {', '.join(profile.messages)}, not {c.input.message}")
    scales = dataclasses.asdict(c.input.custom)
    if c.input.profile == "custom":
        for key, value in scales.items():
            if value is None:
                _fail(f"input.custom.{key}", "required with profile: custom")
    elif any(v is not None for v in scales.values()):
        _fail("input.custom", f"scales are only used with profile: custom (profile is {c.input.profile})")
    method = METHODS[c.estimator.method]
    # the σ only: rest_s still times the rest measurement (the fused filter starts from its gyro bias, its σ_m
    # floored by the magnetometer's σ; the IGN that solves a too-slow input per sample weighs with it)
    changed = [k for k in NOISE_SIGMA_KEYS if getattr(c.noise, k) != getattr(DEFAULTS.noise, k)]
    if not method.sensor_noise and changed:
        key = changed[0]
        _fail(
            f"noise.{key}",
            f"not used by estimator.method {method.name} (its σ are effective, tuned values): set "
            f"{method.settings_section}.{key} "
            "instead, and leave noise (and --accel-std / --mag-std) at the default",
        )
    if c.filter.enabled and c.filter.cutoff_hz >= c.filter.output_rate_hz / 2:
        _fail("filter.cutoff_hz", f"must be below half of filter.output_rate_hz ({c.filter.output_rate_hz / 2:g} Hz)")


def _to_plain(value: Any) -> Any:
    if isinstance(value, MagneticReference):
        return value.to_yaml()
    if dataclasses.is_dataclass(value):
        return {f.name: _to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple):
        return [_to_plain(v) for v in value]
    return value


def merge(low: Mapping[str, Any], high: Mapping[str, Any], path: str = "") -> dict[str, Any]:
    """Raw config data ``high`` over ``low``, key by key (a layer's rule; see the module docstring)."""
    out = dict(low)
    for key, value in high.items():
        sub = f"{path}.{key}" if path else str(key)
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping) and sub not in REPLACE_WHOLE:
            out[key] = merge(out[key], value, sub)
        else:
            out[key] = value
    return out


def _nest(dotted: Mapping[str, Any]) -> dict[str, Any]:
    """``{"estimator.method": "cgn"}`` → ``{"estimator": {"method": "cgn"}}``; a key given both a value and keys
    of its own (``filter=3`` and ``filter.cutoff_hz=5``) is refused, since one would silently lose the other."""
    out: dict[str, Any] = {}
    for key, value in dotted.items():
        *parents, leaf = key.split(".")
        node = out
        for section in itertools.accumulate(parents, lambda above, name: f"{above}.{name}"):
            if section in dotted:
                _fail(section, f"given a value and also the key {key}")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the last silently). A merge
    key's (``<<: *defaults``) keys are not the mapping's own: one given again overrides it, as YAML means; an
    unhashable key is left to PyYAML, which refuses it."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            if not isinstance(key, typing.Hashable):
                continue
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice in one mapping", key_node.start_mark
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _yaml_error(path: str | Path, exc: yaml.YAMLError) -> ConfigError:
    """``PATH:LINE:COLUMN: what`` (1-based, as editors count) for a YAML error with a position."""
    mark = getattr(exc, "problem_mark", None)
    what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
    return ConfigError(f"{where}: not valid YAML: {what}")


def read_yaml(path: str | Path) -> dict[str, Any]:
    """One config file as raw data; a missing or malformed file is a ConfigError naming it (and where)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a YAML text file (byte {exc.start} is not UTF-8)") from None
    try:
        node, data = _load(text)
    except yaml.YAMLError as exc:
        raise _yaml_error(path, exc) from None
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    return _Located(data, _key_lines(node))


def _load(text: str) -> tuple[yaml.Node | None, Any]:
    """The document's node tree (where each key is) and its data, keys given twice refused."""
    loader = _UniqueKeyLoader(text)  # a SafeLoader
    try:
        node = loader.get_single_node()
        return node, loader.construct_document(node) if node is not None else None
    finally:
        loader.dispose()  # type: ignore[no-untyped-call]


class _Located(dict[str, Any]):
    """A config file's data, with the ``line:column`` of each dotted key, for errors that say where."""

    def __init__(self, data: Mapping[str, Any], where: dict[str, str]) -> None:
        super().__init__(data)
        self.where = where


def _key_lines(node: yaml.Node, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode):
                out[f"{prefix}{key.value}"] = f"{key.start_mark.line + 1}:{key.start_mark.column + 1}"
                out.update(_key_lines(value, f"{prefix}{key.value}."))
    return out


def _located(source: str, data: Mapping[str, Any], message: str) -> str:
    """``source:LINE:COLUMN`` for an error about a key the file holds (the nearest enclosing one), else ``source``."""
    where = getattr(data, "where", {})
    key = message.split(":", 1)[0].split("[", 1)[0]  # an element's error is said where its key is
    while key and key not in where:
        key = key.rpartition(".")[0]
    return f"{source}:{where[key]}" if key else source


def from_dict(data: Mapping[str, Any], source: str = "config", *, cross_check: bool = True) -> Config:
    """Validate raw data into a Config; ``cross_check=False`` checks the keys and values only (one layer)."""
    try:
        config = _build(Config, data, "")
        if cross_check:
            _cross_check(config)
    except ConfigError as exc:
        raise ConfigError(f"{_located(source, data, str(exc))}: {exc}") from None
    return config


def layers(
    path: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> list[tuple[str, dict[str, Any]]]:
    """The raw layers, lowest first, each named by its source: file, ``$MAVATTITUDE_CONFIG`` file, flags."""
    env = os.environ if env is None else env
    out: list[tuple[str, dict[str, Any]]] = []
    if path is not None:
        out.append((str(path), read_yaml(path)))
    if env.get(ENV_VAR):
        out.append((f"{ENV_VAR}={env[ENV_VAR]}", read_yaml(env[ENV_VAR])))
    if overrides:
        try:
            out.append(("command-line flags", _nest(overrides)))
        except ConfigError as exc:
            raise ConfigError(f"command-line flags: {exc}") from None
    return out


def load_config(
    path: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> Config:
    """The effective config: defaults < ``path`` < ``$MAVATTITUDE_CONFIG`` file < ``overrides`` (dotted keys).

    Each layer's keys and values are checked on their own first, so an error names the file (or the flags)
    it came from; rules spanning keys are checked on the merged result.
    """
    return merge_layers(layers(path, overrides, env))


def merge_layers(found: list[tuple[str, dict[str, Any]]]) -> Config:
    """The effective config of raw :func:`layers` (lowest first), as :func:`load_config` describes."""
    merged: dict[str, Any] = {}
    for source, data in found:
        from_dict(data, source, cross_check=False)
        merged = merge(merged, data)
    return from_dict(merged, found[0][0] if len(found) == 1 else "effective config")


def describe() -> list[tuple[str, Any, str]]:
    """``(dotted key, default, description)`` for every key, for help texts and the example files' test."""
    rows: list[tuple[str, Any, str]] = []

    def walk(cls: type, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            key = f"{prefix}{f.name}"
            if _check_of(f, hints[f.name]):
                rows.append((key, _to_plain(getattr(cls(), f.name)), f.metadata["doc"]))
            else:
                walk(hints[f.name], f"{key}.")

    walk(Config, "")
    return rows
