"""The scripted fake vehicle: a MAVLink 2 autopilot peer that flies a truth script and scores what it hears.

It behaves like an autopilot on a companion-computer link:

- HEARTBEAT at 1 Hz (wall-clock), as an ArduPilot (or PX4) autopilot, component 1;
- GLOBAL_POSITION_INT (2 Hz by default) and the IMU messages of its profile, encoded by
  :func:`mavattitude.sensors.units.encode` (the project's only MAVLink unit conversion); without a GPS
  fix (``gps_fix``, or :meth:`FakeVehicle.set_gps_fix`) latitude, longitude and altitude 0, as ArduPilot
  sends it with no GPS;
- GPS_RAW_INT when asked for: the script's true ground speed and course, a 3D fix (none without ``gps_fix``);
- with ``other_telemetry``, the rest of a real autopilot's telemetry (:data:`OTHER_TELEMETRY_HZ`: VFR_HUD,
  SYS_STATUS, AHRS2, …, 80 messages a second), none of which the service reads;
- ATTITUDE (10 Hz by default, ``attitude_rate_hz``), as an autopilot's own estimate: the truth, turned
  by ``attitude_error_deg`` (roll, pitch, yaw) to play an autopilot that is off, so a log recorded from
  it gives ``replay`` and the service's cross-check something to compare with;
- SYSTEM_TIME when asked for, its Unix time ``gps_unix_s`` at boot plus the vehicle clock (a GPS date
  other than the machine's); without ``gps_unix_s`` it has no GPS time and denies the request;
- honours MAV_CMD_SET_MESSAGE_INTERVAL (interval µs; −1 stops, 0 restores the default) and answers every
  COMMAND_LONG with COMMAND_ACK. Like ArduPilot Copter it starts with the IMU stream off until asked
  (``stream_on_start`` turns it on), and like ArduPilot it denies the command when param3 is not 0
  (``deny_nonzero_param3``); a slow link caps its IMU streams (``link_max_imu_hz``);
- on ``udpin:`` it serves every peer that has sent it a datagram (pymavlink's multi-client UDP server,
  as ArduPilot and MAVProxy do), so a ground station and the service can share it;
- records every ATTITUDE_QUATERNION, STATUSTEXT and COMMAND_LONG it receives, and scores the attitude
  against the truth at the same vehicle time (:mod:`mavattitude.sim.scoring`);
- answers PARAM_REQUEST_READ of its level trim (AHRS_TRIM_X/Y, ``trim_deg``: its board so turned in the
  frame, its IMU messages the board's, its ATTITUDE and the truth the frame's), of whether it uses each
  compass (COMPASS_USE, COMPASS_USE2, COMPASS_USE3: ``compass_use``) and of its declination (COMPASS_DEC, or
  EKF2_MAG_DECL with the px4 profile: its script's field's, as an autopilot that had a GPS fix there holds it).

The vehicle clock is the script clock scaled by ``speed`` (an accelerated soak runs faster than real
time); ``time_boot_ms``/``time_usec`` count from the last (simulated) boot. Faults are injected through
methods: :meth:`FakeVehicle.send_bytes`, :meth:`inject` (a function over the next
samples: bad values, repeated or shifted times), :meth:`jump_clock`, :meth:`reboot`, :meth:`pause_imu`,
and by changing stream rates.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import threading
import time
from array import array
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavattitude.errors import InputError, LinkError
from mavattitude.estimation.conventions import Array, euler_from_quat
from mavattitude.link.logstreams import compass_use_parameter
from mavattitude.link.mavlink2 import force_mavlink2, mavlink2, mavutil, message_id
from mavattitude.link.source import FIRMWARE_PROFILES
from mavattitude.sensors.magref import DECLINATION_PARAMETERS, declination_parameter
from mavattitude.sensors.mounting import TRIM_PARAMETERS, trim_matrix
from mavattitude.sensors.units import (
    MESSAGES,
    ImuSample,
    Position,
    encode,
    encode_position,
    get_profile,
    time_boot_ms,
    time_usec,
)
from mavattitude.sim.scoring import Comparison, Score, compare, score
from mavattitude.sim.sensors import SensorModel
from mavattitude.sim.trajectory import Script

log = logging.getLogger(__name__)

_IMU_MESSAGE_IDS = frozenset(message_id(name) for name in MESSAGES)
_MSG_GLOBAL_POSITION_INT = mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
_MSG_ATTITUDE = mavlink2.MAVLINK_MSG_ID_ATTITUDE
_MSG_SYSTEM_TIME = mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME
_MSG_GPS_RAW_INT = mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT
_GPS_SATELLITES = 12
_AUTOPILOT = {profile: autopilot for autopilot, profile in FIRMWARE_PROFILES.items()}
_POSITION_RATE_HZ = 2.0
#: A real autopilot's other telemetry, messages a second by type: what the ground station of the real ArduSub dive
#: (../shared/data/real) received beside the streams above and the IMU's, 80 a second in all (``other_telemetry``)
OTHER_TELEMETRY_HZ = {
    **{"AHRS2": 20.0, "NAMED_VALUE_FLOAT": 16.0, "VFR_HUD": 10.0},
    **dict.fromkeys(("AHRS", "HWSTATUS", "EKF_STATUS_REPORT", "VIBRATION", "BATTERY_STATUS", "SYS_STATUS"), 3.0),
    **dict.fromkeys(("POWER_STATUS", "MEMINFO", "NAV_CONTROLLER_OUTPUT", "SERVO_OUTPUT_RAW", "RC_CHANNELS"), 2.0),
    **dict.fromkeys(("SCALED_PRESSURE", "SCALED_PRESSURE2", "MISSION_CURRENT"), 2.0),
}
_HEARTBEAT_PERIOD_S = 1.0
# The sender wakes at least this often (s): the pacing granularity of IMU sends at high rates.
_MAX_SLEEP_S = 0.002


def _vec(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class VehicleConfig:
    connect: str  # pymavlink connection string (udpin:127.0.0.1:0 binds an ephemeral port)
    profile: str = "ardupilot"  # unit profile of the IMU messages (sensors.units)
    message: str = "RAW_IMU"  # the IMU message streamed by default
    system_id: int = 1
    component_id: int = 1
    stream_on_start: bool = False  # ArduPilot Copter: silent until SET_MESSAGE_INTERVAL
    deny_nonzero_param3: bool = True  # ArduPilot denies SET_MESSAGE_INTERVAL with param3 ≠ 0
    speed: float = 1.0  # vehicle seconds per real second
    # Hold the script at its start until the IMU stream is first asked for (tests see the whole script);
    # the vehicle clock runs from boot regardless.
    fly_when_asked: bool = False
    # ArduPilot's HIGHRES_IMU magnetometer is 10⁶ too large (a known bug): reproduce it when asked.
    highres_mag_bug: bool = False
    seed: int = 0
    # A slow link (ArduPilot SITL at 57600 baud carries ~139 RAW_IMU a second): IMU streams are sent at most
    # this fast, whatever rate was asked for (the request is still ACCEPTED, as ArduPilot does). None: no limit.
    link_max_imu_hz: float | None = None
    signing_key: bytes | None = None  # sign outgoing packets with this key
    home_lat_deg: float = 47.3977
    home_lon_deg: float = 8.5456
    home_alt_m: float = 488.0
    attitude_rate_hz: float = 10.0  # ATTITUDE streamed from boot (0: only when asked for)
    attitude_error_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the autopilot's error: roll, pitch, yaw
    gps_unix_s: float | None = None  # the GPS's Unix time at boot, for SYSTEM_TIME (None: no GPS time)
    gps_fix: bool = True  # False: no GPS position (GLOBAL_POSITION_INT all 0, as ArduPilot without a GPS)
    # ArduPilot's level trim, roll and pitch: the autopilot's board sits so turned in the frame; its IMU messages
    # are the board's, its ATTITUDE the frame's, and PARAM_REQUEST_READ of AHRS_TRIM_X/Y answers it
    trim_deg: tuple[float, float] = (0.0, 0.0)
    compass_use: tuple[int, int, int] = (1, 1, 1)  # COMPASS_USE, COMPASS_USE2, COMPASS_USE3: which it heads by
    other_telemetry: bool = False  # also stream OTHER_TELEMETRY_HZ from boot (their fields ones, their values moot)


@dataclass(frozen=True)
class ImuRow:
    """One IMU sample about to be sent (what a fault injected with :meth:`FakeVehicle.inject` sees)."""

    script_s: float
    vehicle_s: float
    acc_mps2: tuple[float, float, float]
    gyr_radps: tuple[float, float, float]
    mag_uT: tuple[float, float, float] | None


@dataclass
class _Stream:
    """A telemetry stream, paced by the clock."""

    rate_hz: float
    next_t_s: float  # when the next is due, time.monotonic()


@dataclass
class _ImuStream:
    """An IMU stream on its rate's grid of script time: sample ``next_tick`` is due at ``next_tick / rate_hz``."""

    rate_hz: float
    next_tick: int = 0

    def restart(self, script_s: float) -> _ImuStream:
        """Go on from the first tick at or after ``script_s``; returns itself."""
        self.next_tick = math.ceil(script_s * self.rate_hz)
        return self

    def set_rate(self, rate_hz: float) -> None:
        """Go on at ``rate_hz`` from the next sample's time (the same tick when the rate is the same)."""
        self.next_tick = math.ceil(self.next_tick * rate_hz / self.rate_hz)  # exact where the two grids meet
        self.rate_hz = rate_hz

    @property
    def next_t_s(self) -> float:
        return self.next_tick / self.rate_hz


def _next_deadline(deadline_s: float, now_s: float, period_s: float) -> float:
    """The first deadline after ``now_s`` on the grid ``deadline_s + k · period_s``.

    Deadlines are absolute, so the time a send takes and a late wake-up do not stretch the period (the
    rate stays what was asked); ticks missed by a stall are skipped, not sent in a burst of stale values.
    """
    return deadline_s + period_s * (1 + max(0.0, (now_s - deadline_s) // period_s))


@dataclass
class _Epoch:
    """Vehicle time = script time − boot_script_s + clock_offset_s while this epoch holds."""

    boot_script_s: float = 0.0
    clock_offset_s: float = 0.0

    def vehicle_time(self, script_s: float) -> float:
        return script_s - self.boot_script_s + self.clock_offset_s

    def script_time(self, vehicle_s: float) -> float:
        return vehicle_s + self.boot_script_s - self.clock_offset_s


def _filled_message(name: str) -> Any:
    """A message of type ``name`` with every field one (strings "1"): a frame of its usual length."""
    cls = getattr(mavlink2, f"MAVLink_{name.lower()}_message")
    values: list[Any] = []
    for field_name, kind in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        one: Any = b"1" if kind == "char" else 1.0 if kind in ("float", "double") else 1
        length = cls.array_lengths[cls.ordered_fieldnames.index(field_name)]
        values.append(one if length == 0 or kind == "char" else [one] * length)
    return cls(*values)


class FakeVehicle:
    """Run with ``with FakeVehicle(...) as v:`` (or :meth:`start` / :meth:`stop`)."""

    def __init__(self, script: Script, sensors: SensorModel, config: VehicleConfig) -> None:
        self.script = script
        self.sensors = sensors
        self.config = config
        self._rng = np.random.default_rng(config.seed)
        self._profile = get_profile(config.profile)
        self._profile.scale(config.message)  # SensorError now, for a message the profile cannot send
        # the IMU messages its autopilot has: another one asked for is denied, as a real one has no such stream
        self._imu_ids = frozenset(message_id(name) for name in self._profile.messages)
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._drop_requested = threading.Event()
        self._threads: list[threading.Thread] = []
        self._epoch = _Epoch()
        self._imu_paused = False
        self._down_until_mono = -math.inf  # restarting until then (reboot): silent and deaf
        self._gps_fix = config.gps_fix
        # its readings are its board's: a frame row vector v turns into the board's as v · T (Tᵀ v, as a column)
        self._frame_to_board_rows = trim_matrix(*np.radians(config.trim_deg))
        self._streams: dict[int, _Stream | _ImuStream] = {}
        # the telemetry it sends (paced by the clock) and how
        self._telemetry: dict[int, Callable[[float], None]] = {
            _MSG_GLOBAL_POSITION_INT: self._send_position,
            _MSG_ATTITUDE: self._send_attitude,
            _MSG_GPS_RAW_INT: self._send_gps_raw,
        }
        if config.gps_unix_s is not None:
            self._telemetry[_MSG_SYSTEM_TIME] = self._send_system_time
        for name in OTHER_TELEMETRY_HZ if config.other_telemetry else ():
            self._telemetry[message_id(name)] = functools.partial(self._send_as_is, _filled_message(name))
        self._peer_order: list[tuple[str, int]] = []
        self._fault: tuple[Callable[[list[ImuRow]], list[ImuRow]], float, threading.Event] | None = None
        # Records (appended by the receive thread, read under self._cond).
        self.attitude_log: list[tuple[float, float, tuple[float, float, float, float], _Epoch, int]] = []
        self.statustexts: list[str] = []
        self.attitudes_sent_s: list[float] = []  # vehicle time of each ATTITUDE sent (appended by the sender)
        self.thread_errors: list[str] = []
        self.commands: list[Any] = []
        self.received: Counter[tuple[int, int, str]] = Counter()  # (system, component, type)
        self._sent_t_s = array("d")
        self._sent_mono_s = array("d")
        self.imu_sent = 0
        self.conn = self._open(config)
        self._t0_mono = time.monotonic()  # the vehicle's boot
        self._script_t0_mono: float | None = None if config.fly_when_asked else self._t0_mono
        self._default_streams()

    # --- set-up -----------------------------------------------------------------------------------------

    def _open(self, config: VehicleConfig) -> Any:
        try:
            conn = mavutil.mavlink_connection(
                config.connect, source_system=config.system_id, source_component=config.component_id
            )
        except (OSError, ValueError) as exc:
            raise LinkError(f"fake vehicle cannot open {config.connect!r}: {exc}") from exc
        force_mavlink2(conn)
        if config.signing_key is not None:
            conn.setup_signing(config.signing_key, sign_outgoing=True, allow_unsigned_callback=lambda *_: True)
        # pymavlink's recv changes what its write iterates (udpin adds each new peer to conn.clients, tcpin
        # accepts into conn.port), and they run on two threads here: each recv (a non-blocking read; the
        # wait for data stays outside) takes the send lock, or a new peer's first datagram kills the sender.
        recv = conn.recv

        def recv_locked(n: int | None = None) -> Any:
            with self._send_lock:
                return recv(n)

        conn.recv = recv_locked
        return conn

    def peers(self) -> list[tuple[str, int]]:
        """The UDP addresses that have talked to this (``udpin``) vehicle, first heard first."""
        with self._cond:
            return list(self._peer_order)

    @property
    def port(self) -> int:
        """The local port (for ``udpin:…:0``/``tcpin:…:0``: the ephemeral port the service must reach)."""
        sock = self.conn.listen if isinstance(self.conn, mavutil.mavtcpin) else self.conn.port
        return int(sock.getsockname()[1])

    def drop_client(self) -> None:
        """A ``tcpin`` vehicle closes its client's connection (a cable or router dropping the link)."""
        if not isinstance(self.conn, mavutil.mavtcpin):
            raise LinkError("only a tcpin vehicle has a client connection to drop")
        self._drop_requested.set()  # done by the receive thread, which owns the socket it reads

    def _drop_if_requested(self) -> None:
        if not self._drop_requested.is_set():
            return
        self._drop_requested.clear()
        with self._send_lock:
            if self.conn.port is not None:
                self.conn.port.close()
                self.conn.port = None
                self.conn.fd = self.conn.listen.fileno()

    def _default_streams(self) -> None:
        now = time.monotonic()  # telemetry streams run on the monotonic clock (IMU streams on the script's)
        self._streams = {_MSG_GLOBAL_POSITION_INT: _Stream(_POSITION_RATE_HZ, now)}
        if self.config.attitude_rate_hz > 0:
            self._streams[_MSG_ATTITUDE] = _Stream(self.config.attitude_rate_hz, now)
        if self.config.stream_on_start:
            self._set_stream(message_id(self.config.message), self.sensors.rate_hz)
        for name, rate_hz in OTHER_TELEMETRY_HZ.items() if self.config.other_telemetry else ():
            self._streams[message_id(name)] = _Stream(rate_hz, now)

    def start(self) -> FakeVehicle:
        for target in (self._send_loop, self._receive_loop):
            thread = threading.Thread(
                target=self._guarded, args=(target,), name=f"fake-vehicle-{target.__name__}", daemon=True
            )
            thread.start()
            self._threads.append(thread)
        return self

    def _guarded(self, loop: Callable[[], None]) -> None:
        """Run a thread's loop; a crash is logged and kept in :attr:`thread_errors` for the tests to show."""
        try:
            loop()
        except Exception as exc:
            log.exception("fake vehicle: %s died", loop.__name__)
            with self._cond:
                self.thread_errors.append(f"{loop.__name__}: {type(exc).__name__}: {exc}")
                self._cond.notify_all()

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self.conn.close()

    def __enter__(self) -> FakeVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- clocks -----------------------------------------------------------------------------------------

    def script_time(self, mono_s: float | None = None) -> float:
        """Script seconds since the script started (0 while a ``fly_when_asked`` vehicle waits)."""
        if self._script_t0_mono is None:
            return 0.0
        mono_s = time.monotonic() if mono_s is None else mono_s
        return (mono_s - self._script_t0_mono) * self.config.speed

    @property
    def flying(self) -> bool:
        """The script has started (a ``fly_when_asked`` vehicle: once asked for the IMU stream)."""
        return self._script_t0_mono is not None

    def vehicle_time(self, script_s: float) -> float:
        return self._epoch.vehicle_time(script_s)

    def jump_clock(self, delta_s: float) -> None:
        """Shift the vehicle's timestamps by ``delta_s`` (negative: time goes back) from now on."""
        if self.vehicle_time(self.script_time()) + delta_s < 0:
            raise InputError(f"jump_clock({delta_s}) would take the vehicle clock below zero (use reboot())")
        with self._cond:
            self._epoch = dataclasses.replace(self._epoch, clock_offset_s=self._epoch.clock_offset_s + delta_s)

    def reboot(self, down_s: float = 0.0) -> None:
        """A simulated reboot: boot time restarts at 0 and the streams fall back to their defaults. For ``down_s``
        (wall-clock) before it boots it sends nothing and hears nothing, as an autopilot while it restarts."""
        self._down_until_mono = time.monotonic() + down_s
        with self._cond:
            self._epoch = _Epoch(boot_script_s=self.script_time() + down_s * self.config.speed)
        self._default_streams()

    def set_gps_fix(self, fix: bool = True) -> None:
        """A GPS fix from now on (its position the home), or none (GLOBAL_POSITION_INT all 0)."""
        self._gps_fix = fix

    def pause_imu(self, paused: bool = True) -> None:
        """Stop (or resume) IMU messages while the script and everything else go on.

        Once it returns, :attr:`imu_sent` stays put while paused (each sample is counted and checked under
        the same lock), so a test can compare it with what the service received."""
        with self._cond:
            self._imu_paused = paused
        if not paused:  # resume from now, not with a backlog of the silent time
            now = self.script_time()
            with self._cond:
                for stream in self._streams.values():
                    if isinstance(stream, _ImuStream):
                        stream.restart(now)

    def set_rate(self, message: str, rate_hz: float | None) -> None:
        """Stream ``message`` at ``rate_hz`` (None stops it), as if a SET_MESSAGE_INTERVAL arrived."""
        self._set_stream(message_id(message), rate_hz)

    def stream_rate(self, message: str) -> float | None:
        stream = self._streams.get(message_id(message))
        return None if stream is None else stream.rate_hz

    # --- sending ----------------------------------------------------------------------------------------

    def send(self, msg: Any) -> None:
        with self._send_lock:
            self.conn.mav.send(msg)

    def send_bytes(self, data: bytes) -> None:
        """Raw bytes on the link (garbage, truncated or corrupted frames)."""
        with self._send_lock:
            self.conn.write(data)

    def encode(self, sample: ImuSample, message: str | None = None) -> Any:
        """The MAVLink ``message`` (default: the configured one) of an SI sample in this vehicle's profile."""
        kind = message or self.config.message
        if self.config.highres_mag_bug and kind == "HIGHRES_IMU" and sample.mag_uT is not None:
            sample = dataclasses.replace(sample, mag_uT=tuple(1e6 * b for b in sample.mag_uT))
        fields = encode(sample, self._profile, kind)
        return getattr(mavlink2, f"MAVLink_{kind.lower()}_message")(**fields)

    def _send_loop(self) -> None:
        next_heartbeat = time.monotonic()
        while not self._stop.is_set():
            mono = time.monotonic()
            if mono < self._down_until_mono:
                self._stop.wait(min(self._down_until_mono - mono, _MAX_SLEEP_S))
                continue
            if mono >= next_heartbeat:
                self._send_heartbeat()
                next_heartbeat = _next_deadline(next_heartbeat, mono, _HEARTBEAT_PERIOD_S)
            now = self.script_time(mono)
            wake = now + _MAX_SLEEP_S * self.config.speed
            for msg_id, stream in list(self._streams.items()):
                if not isinstance(stream, _ImuStream):  # telemetry: paced by the clock, flying or not
                    if mono >= stream.next_t_s:
                        self._telemetry[msg_id](now)
                        period_s = 1.0 / (stream.rate_hz * self.config.speed)
                        stream.next_t_s = _next_deadline(stream.next_t_s, mono, period_s)
                    continue
                if not self._imu_paused:
                    self._send_imu_until(msg_id, stream, now)
                wake = min(wake, stream.next_t_s)
            delay = (wake - self.script_time()) / self.config.speed
            if delay > 0:
                self._stop.wait(min(delay, _MAX_SLEEP_S))

    def _send_imu_until(self, msg_id: int, stream: _ImuStream, now_s: float) -> None:
        with self._cond:  # the rate and the tick counted on its grid change together (_set_stream)
            sensors = self.sensors.at_rate(stream.rate_hz)
            t, stream.next_tick = sensors.ticks(stream.next_tick, now_s, self._rng)
        # One epoch for the batch, and only its samples: a reboot (another thread) may have come after this
        # loop took its time, and jitter may put a sample just before the boot. Samples due before the boot
        # are lost with it; stamped in the new epoch they would go out with a negative time.
        epoch = self._epoch
        t = t[t >= epoch.boot_script_s]
        if not len(t):
            return
        acc, gyr, mag = (v @ self._frame_to_board_rows for v in sensors.measure(self.script, t, self._rng))
        name = mavlink2.mavlink_map[msg_id].msgname
        rows = [ImuRow(t[i], epoch.vehicle_time(t[i]), _vec(acc[i]), _vec(gyr[i]), _vec(mag[i])) for i in range(len(t))]
        for row in self._apply_fault(rows):
            msg = self.encode(ImuSample(row.vehicle_s, row.acc_mps2, row.gyr_radps, row.mag_uT), name)
            # Logged before the send, so the log never lags the datagram (latency is then an upper bound
            # by the pack + sendto time, a few µs).
            with self._cond:
                if self._imu_paused:
                    return
                self._sent_t_s.append(row.script_s)
                self._sent_mono_s.append(time.monotonic())
                self.imu_sent += 1
            self.send(msg)

    def inject(self, fault: Callable[[list[ImuRow]], list[ImuRow]], duration_s: float) -> threading.Event:
        """Pass the IMU samples of the next ``duration_s`` (script time) through ``fault`` before sending.

        ``fault`` may change values or times, repeat or drop rows. The returned event is set once the
        first sample after the window has been sent (the fault is over).
        """
        done = threading.Event()
        with self._cond:
            self._fault = (fault, self.script_time() + duration_s, done)
        return done

    def _apply_fault(self, rows: list[ImuRow]) -> list[ImuRow]:
        with self._cond:
            fault = self._fault
        if fault is None:
            return rows
        fn, end_s, done = fault
        inside = [r for r in rows if r.script_s < end_s]
        after = [r for r in rows if r.script_s >= end_s]
        out = (fn(inside) if inside else []) + after
        if after:
            with self._cond:
                self._fault = None
            done.set()
        return out

    def _send_as_is(self, msg: Any, now_s: float) -> None:
        self.send(msg)

    def _send_heartbeat(self) -> None:
        autopilot = _AUTOPILOT.get(self.config.profile, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA)
        self.send(
            mavlink2.MAVLink_heartbeat_message(
                mavlink2.MAV_TYPE_QUADROTOR,
                autopilot,
                mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                0,
                mavlink2.MAV_STATE_ACTIVE,
                3,
            )
        )

    def _send_position(self, now_s: float) -> None:
        truth = self.script.sample([now_s])
        vel_cms = np.round(truth.vel_ned_mps[0] * 100).astype(int)
        cfg = self.config
        home = Position(cfg.home_lat_deg, cfg.home_lon_deg, cfg.home_alt_m)
        position = encode_position(home) if self._gps_fix else (0, 0, 0)  # no fix: ArduPilot sends zeros
        self.send(
            mavlink2.MAVLink_global_position_int_message(
                time_boot_ms(max(0.0, self.vehicle_time(now_s))),
                *position,
                0,
                *(int(np.clip(v, -32768, 32767)) for v in vel_cms),
                65535,
            )
        )

    def _send_gps_raw(self, now_s: float) -> None:
        """GPS_RAW_INT when asked for: the script's true ground speed and course (cm/s, cdeg), a 3D fix with 12
        satellites (none without ``gps_fix``), stamped with the vehicle time since boot, as ArduPilot does."""
        vn, ve, _ = self.script.sample([now_s]).vel_ned_mps[0].tolist()
        speed_cms = min(round(math.hypot(vn, ve) * 100.0), 65534)
        cog_cdeg = round(math.degrees(math.atan2(ve, vn)) * 100.0) % 36000
        cfg = self.config
        home = encode_position(Position(cfg.home_lat_deg, cfg.home_lon_deg, cfg.home_alt_m))
        fix, position, satellites = (3, home, _GPS_SATELLITES) if self._gps_fix else (0, (0, 0, 0), 0)
        vehicle_us = time_usec(max(0.0, self.vehicle_time(now_s)))
        unknown = 65535  # eph, epv: not known
        self.send(
            mavlink2.MAVLink_gps_raw_int_message(
                vehicle_us, fix, *position, unknown, unknown, speed_cms, cog_cdeg, satellites
            )
        )

    def _send_system_time(self, now_s: float) -> None:
        vehicle_s = max(0.0, self.vehicle_time(now_s))
        unix_us = round(((self.config.gps_unix_s or 0.0) + vehicle_s) * 1e6)  # asked for only when set
        self.send(mavlink2.MAVLink_system_time_message(unix_us, time_boot_ms(vehicle_s)))

    def _send_attitude(self, now_s: float) -> None:
        truth = self.script.sample([now_s])
        roll, pitch, yaw = euler_from_quat(truth.q[0]) + np.radians(self.config.attitude_error_deg)
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi  # the error may carry yaw past ±180°
        stamp_ms = time_boot_ms(max(0.0, self.vehicle_time(now_s)))
        self.send(mavlink2.MAVLink_attitude_message(stamp_ms, roll, pitch, yaw, *map(float, truth.gyr_radps[0])))
        self.attitudes_sent_s.append(stamp_ms / 1000.0)

    # --- receiving --------------------------------------------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            self._drop_if_requested()
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except (OSError, ValueError) as exc:  # ValueError: select on a connection just dropped
                if self._stop.is_set():
                    return
                log.debug("fake vehicle: receive error %s", exc)
                continue
            if msg is None:
                continue
            mono = time.monotonic()
            for address in getattr(self.conn, "clients", ()):
                if address not in self._peer_order:
                    with self._cond:
                        self._peer_order.append(address)
            self._handle(msg, mono)

    def _handle(self, msg: Any, mono: float) -> None:
        if mono < self._down_until_mono:
            return
        kind = msg.get_type()
        with self._cond:  # every message wakes the waiters (a heartbeat at least once a second)
            self.received[(msg.get_srcSystem(), msg.get_srcComponent(), kind)] += 1
            if kind == "ATTITUDE_QUATERNION":
                q = (msg.q1, msg.q2, msg.q3, msg.q4)
                self.attitude_log.append((mono, msg.time_boot_ms / 1000.0, q, self._epoch, msg.get_srcSystem()))
            elif kind == "ATTITUDE_QUATERNION_COV":
                self._timed_to_the_microsecond(msg)
            elif kind == "STATUSTEXT":
                self.statustexts.append(msg.text)
            self._cond.notify_all()
        if kind == "COMMAND_LONG" and msg.target_system in (0, self.config.system_id):
            self._command(msg)
        elif kind == "PARAM_REQUEST_READ" and msg.target_system in (0, self.config.system_id):
            self._parameter(msg.param_id)

    def _timed_to_the_microsecond(self, msg: Any) -> None:
        """The covariance sent with the attitude before it (the same time, in µs): that output's time to the µs, where
        its time_boot_ms is rounded to the ms (an output per sample of a slow input carries its sample's time, and
        the scoring pairs each output with the sample at or after it). Called under ``_cond``."""
        if not self.attitude_log:
            return
        mono, t_s, q, epoch, system = self.attitude_log[-1]
        if system == msg.get_srcSystem() and round(t_s * 1e3) == round(msg.time_usec / 1e3):
            self.attitude_log[-1] = (mono, msg.time_usec / 1e6, q, epoch, system)

    def _parameter(self, name: str) -> None:
        """PARAM_VALUE of one of the parameters it has (its level trim, its compasses' use); another name is not
        answered, as ArduPilot does not."""
        parameters = dict(zip(TRIM_PARAMETERS, np.radians(self.config.trim_deg).tolist(), strict=True))
        parameters |= {compass_use_parameter(k): float(use) for k, use in enumerate(self.config.compass_use)}
        north_uT, east_uT, _ = self.script.mag_ned_uT
        declination = declination_parameter(self.config.profile)  # in its autopilot's unit
        parameters[declination] = math.degrees(math.atan2(east_uT, north_uT)) / DECLINATION_PARAMETERS[declination]
        if name in parameters:
            real32 = mavlink2.MAV_PARAM_TYPE_REAL32
            self.send(mavlink2.MAVLink_param_value_message(name.encode(), parameters[name], real32, len(parameters), 0))

    def _command(self, msg: Any) -> None:
        result = mavlink2.MAV_RESULT_UNSUPPORTED
        if msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(msg.param1), msg.param2, msg.param3)
        with self._cond:
            self.commands.append(msg)
            self._cond.notify_all()
        self.send(
            mavlink2.MAVLink_command_ack_message(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        )

    def _set_interval(self, msg_id: int, interval_us: float, param3: float) -> int:
        if msg_id not in self._imu_ids and msg_id not in self._telemetry:
            return mavlink2.MAV_RESULT_DENIED
        if self.config.deny_nonzero_param3 and param3 != 0:
            return mavlink2.MAV_RESULT_DENIED
        if interval_us < 0:
            self._streams.pop(msg_id, None)
        elif interval_us == 0:
            defaults = {_MSG_GLOBAL_POSITION_INT: _POSITION_RATE_HZ, _MSG_ATTITUDE: self.config.attitude_rate_hz}
            on = msg_id in defaults or (self.config.stream_on_start and msg_id == message_id(self.config.message))
            rate_hz = defaults.get(msg_id, self.sensors.rate_hz)
            self._set_stream(msg_id, rate_hz if on and rate_hz > 0 else None)
        else:
            self._set_stream(msg_id, 1e6 / interval_us)
        return mavlink2.MAV_RESULT_ACCEPTED

    def _set_stream(self, msg_id: int, rate_hz: float | None) -> None:
        if rate_hz is None:
            self._streams.pop(msg_id, None)
            return
        if msg_id in _IMU_MESSAGE_IDS:
            if self._script_t0_mono is None:
                self._take_off()
            if self.config.link_max_imu_hz is not None:
                rate_hz = min(rate_hz, self.config.link_max_imu_hz)
        with self._cond:  # the send loop reads an IMU stream's rate and tick under this lock
            stream = self._streams.get(msg_id)
            if isinstance(stream, _ImuStream):
                stream.set_rate(rate_hz)
            elif msg_id in _IMU_MESSAGE_IDS:
                self._streams[msg_id] = _ImuStream(rate_hz).restart(self.script_time())
            elif stream is None:
                self._streams[msg_id] = _Stream(rate_hz, time.monotonic())
            else:
                stream.rate_hz = rate_hz

    def _take_off(self) -> None:
        """Start the script now; the vehicle clock runs on from where it was (``fly_when_asked``)."""
        now = time.monotonic()
        with self._cond:
            self._epoch = dataclasses.replace(self._epoch, boot_script_s=-(now - self._t0_mono) * self.config.speed)
            self._script_t0_mono = now

    # --- waiting and scoring ----------------------------------------------------------------------------

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until ``predicate()`` (evaluated under the record lock) holds, or the time-out passes."""
        with self._cond:
            return self._cond.wait_for(predicate, timeout=timeout_s)

    def wait_for_outputs(self, count: int, timeout_s: float) -> bool:
        """Wait until ``count`` ATTITUDE_QUATERNION messages have arrived in total."""
        return self.wait_until(lambda: len(self.attitude_log) >= count, timeout_s)

    def wait_for_script_time(self, script_s: float, timeout_s: float) -> bool:
        """Wait until an output describing script time ``script_s`` or later has arrived."""

        def reached() -> bool:
            if not self.attitude_log:
                return False
            _, t_vehicle, _, epoch, _ = self.attitude_log[-1]
            return epoch.script_time(t_vehicle) >= script_s

        return self.wait_until(reached, timeout_s)

    def outputs_since(self, index: int = 0) -> tuple[Array, Array, Array]:
        """``(recv_mono_s, script_time_s, q)`` of outputs from ``index`` on."""
        with self._cond:
            rows = self.attitude_log[index:]
        if not rows:
            return np.empty(0), np.empty(0), np.empty((0, 4))
        mono = np.array([r[0] for r in rows])
        script_t = np.array([epoch.script_time(t_vehicle) for _, t_vehicle, _, epoch, _ in rows])
        return mono, script_t, np.array([r[2] for r in rows], dtype=float)

    def sent_log(self) -> tuple[Array, Array]:
        """``(script_time_s, send_mono_s)`` of every IMU message sent, in send order."""
        with self._cond:
            return np.array(self._sent_t_s), np.array(self._sent_mono_s)

    def comparison(self, index: int = 0, since_script_s: float = -np.inf) -> Comparison:
        mono, t, q = self.outputs_since(index)
        keep = t >= since_script_s
        sent_t, sent_mono = self.sent_log()
        order = np.argsort(sent_t, kind="stable")
        q_true = self.script.attitude(t[keep]) if keep.any() else np.empty((0, 4))
        return compare(t[keep], q[keep], mono[keep], q_true, sent_t[order], sent_mono[order])

    def score(self, index: int = 0, since_script_s: float = -np.inf) -> Score:
        return score(self.comparison(index, since_script_s))
