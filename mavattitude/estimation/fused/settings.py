"""The gyro-aided filter's settings: one frozen dataclass, each field with its range and description.

The same fields are the ``estimator.fused`` section of the YAML config (:mod:`mavattitude.config` reads
the range and description from each field's metadata, so a key is checked once, by the same rule, in the
file and here). Units are in the names; the dimensionless ones end in ``_fraction``, ``_gain`` or
``_factor``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import STANDARD_GRAVITY_MPS2
from mavattitude.fields import ranged


@dataclass(frozen=True)
class FusedSettings:
    """Tuning of the gyro-aided filter (one configuration for every vehicle unless a config says otherwise).

    The σ values are *effective* noise: they include model error (sensor calibration residue,
    non-gravitational acceleration, local field) as well as sensor noise, which is why they are far above
    a data sheet's figures. ``docs/fused.md`` has the equations and what each value was tuned on.
    """

    gyro_noise_radps: float = ranged(0.003, "σ_g: gyro angle random walk, rad/s/√Hz (effective)")
    gyro_scale_fraction: float = ranged(0.005, "s_g: gyro scale-factor error, per rad turned", hi=0.5)
    gyro_bias_walk_radps2: float = ranged(2e-5, "σ_b: gyro bias random walk, rad/s/√s")
    gyro_bias_init_radps: float = ranged(0.02, "σ_b0: start-up gyro bias uncertainty, rad/s")
    accel_std_mps2: float = ranged(0.1333, "σ_a: pre-filtered specific force σ per axis, m/s²", lo_open=True)
    accel_lowpass_s: float = ranged(
        1.333, "τ_a: the earth-frame accelerometer pre-filter the tilt measures, s (0: off)", hi=60.0
    )
    accel_rejection_lowpass_s: float = ranged(
        0.7,
        "τ_j: the same pre-filter for the ‖a‖ the rejection watches (shorter: sees an acceleration sooner), s",
        hi=60.0,
    )
    accel_lag_gain: float = ranged(3.0, "k_d: σ_a added per m/s² between the two pre-filters' outputs")
    accel_norm_gain: float = ranged(8.0, "k_n: σ_a added per m/s² of ‖a‖ − g (of the short pre-filter)")
    mag_std_uT: float = ranged(3.75, "σ_m: magnetometer σ per axis, µT", lo_open=True)
    mag_norm_tolerance_fraction: float = ranged(
        0.1, "τ_n: ‖B‖ off its learnt value by this fraction is a disturbance", hi=10.0, lo_open=True
    )
    mag_dip_tolerance_deg: float = ranged(
        10.0, "τ_δ: dip off its reference by this much is a disturbance, deg", hi=90.0
    )
    mag_reference_s: float = ranged(
        20.0,
        "τ_ref: ‖B‖ and the dip are learnt from clean field: a mean over the first τ_ref, then a low-pass of this"
        " time constant, s",
        lo_open=True,
    )
    mag_relearn_s: float = ranged(
        60.0, "T_new: a field disturbed this long without a break is adopted (it sets heading only), s", lo_open=True
    )
    mag_soft_fraction: float = ranged(
        0.35, "d₀: σ_m inflation scale below the disturbance threshold (σ_m² × (1 + (d/d₀)⁶))", lo_open=True
    )
    mag_skew_s: float = ranged(
        0.02, "τ_m: σ_m added per µT/s of the field's turn in the body (‖ω × m‖): the sample-time skew, s", hi=1.0
    )
    mag_recovery_factor: float = ranged(10.0, "ρ₀: σ_m² multiplier just after a long disturbance", lo=1.0)
    mag_recovery_s: float = ranged(3.0, "T_r: the recovery ramp's length, s", hi=3600.0)
    mag_offset_window_s: float = ranged(
        3.0,
        "a disturbance this long, turning, with a constant body-frame residual: learnt as hard iron, s (0: off)",
        hi=3600.0,
    )
    mag_offset_turn_fraction: float = ranged(
        0.05, "the turn the offset needs: 1 − ‖mean predicted field direction‖ over the window", hi=1.0
    )
    mag_offset_scale_r2: float = ranged(
        0.5,
        "a window whose residual follows the predicted field direction this much (r², the share of its spread a"
        " field-strength error explains: more than half, the likelier cause) is refused as hard iron",
        hi=1.0,
    )
    gps_max_accel_mps2: float = ranged(
        20.0, "a GPS velocity step implying more than this acceleration is a glitch, m/s² (0: GPS velocity unused)"
    )
    gps_min_satellites: float = ranged(6.0, "GPS velocities from fewer satellites are not used", hi=255.0)
    gps_max_interval_s: float = ranged(
        1.0,
        "GPS fixes further apart are not differenced (a 2 Hz stream is); an acceleration is dropped this long after, s",
        hi=10.0,
    )
    gps_latency_s: float = ranged(
        0.1, "the GPS receiver's latency: its velocity is this much older than its fix time, s", hi=2.0
    )
    rest_gyro_threshold_radps: float = ranged(math.radians(2.0), "rest: gyro deviation and rate below this, rad/s")
    rest_accel_threshold_mps2: float = ranged(0.5, "rest: accelerometer deviation below this, m/s²")
    rest_min_s: float = ranged(1.5, "rest: still for this long before the zero-rate update, s", hi=3600.0)
    rest_filter_s: float = ranged(0.5, "τ_r: the rest detector's low-pass time constant, s", hi=60.0, lo_open=True)
    rest_gyro_std_radps: float = ranged(0.002, "σ_r: the zero-rate update's σ, rad/s (0: off)")
    gravity_mps2: float = ranged(STANDARD_GRAVITY_MPS2, "g, m/s²", lo=1.0, hi=100.0)
    update_rate_hz: float = ranged(50.0, "measurement updates per second, Hz", hi=1000.0, lo_open=True)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            lo, hi, lo_open = f.metadata["range"]
            if not (math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi):
                bounds = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
                raise InputError(f"FusedSettings.{f.name} must be finite and in {bounds}, got {value!r}")
