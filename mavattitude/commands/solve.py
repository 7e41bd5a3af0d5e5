"""`mavattitude solve INPUT.csv -o OUT.csv`: the service's pipeline, offline, over a CSV of samples.

Input columns (any order, others ignored; .csv.gz is read as gzip):
  t_s (s); acc_x_mps2, acc_y_mps2, acc_z_mps2 (specific force, body FRD: -9.81 on z when level);
  mag_x_uT, mag_y_uT, mag_z_uT; optionally gyr_x_radps, gyr_y_radps, gyr_z_radps.
Output columns:
  t_s, qw, qx, qy, qz (body -> NED), roll_deg, pitch_deg, yaw_deg (ZYX), iterations, converged (1/0),
  cov_xx_rad2, cov_xy_rad2, cov_xz_rad2, cov_yy_rad2, cov_yz_rad2, cov_zz_rad2 (the predicted covariance of
  the body-frame error angles, rad², upper triangle; nan where the geometry gives none).
The samples go through the same pipeline as the service: with the filter (default) one row per output
tick (50 Hz), with --no-filter one row per input row that could be solved. Rows that could not be solved
are counted in the summary on stderr, never written. The magnetic reference: --declination/--inclination,
--mag-ref-ned, or the config's; with reference.magnetic auto (the default) a CSV, which holds no position for
the World Magnetic Model, is treated as replay treats a log without GPS: after reference.position_wait_s the
field is measured from the compass while the vehicle is still, heading is magnetic north, and the rows
before it are not solved (the fused method tracks roll and pitch meanwhile).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import yaml

from mavattitude.commands import about
from mavattitude.commands._offline import (
    PROGRESS_MIN_SAMPLES,
    Progress,
    add_config_arguments,
    config_from_args,
    summarise,
    write_outputs,
)
from mavattitude.config import Config
from mavattitude.errors import ConfigError, DataFileError
from mavattitude.estimation import METHODS
from mavattitude.files import (
    ACC_COLUMNS,
    GYR_COLUMNS,
    LOG_SUFFIXES,
    MAG_COLUMNS,
    TIME_COLUMN,
    read_columns,
    refuse_overwriting,
)

#: Slower than this an IMU's CSV is more likely a time column in milliseconds or microseconds than a real rate
SLOW_TIME_COLUMN_HZ = 1.0


def time_unit_hint(rate_hz: float) -> str | None:
    """What a CSV's median rate ``rate_hz`` would be if its t_s were in ms or µs, where it is too slow for seconds."""
    if not rate_hz < SLOW_TIME_COLUMN_HZ:  # (NaN: one sample)
        return None
    return (
        f"t_s advances {1.0 / rate_hz:.3g} s a sample ({rate_hz:.3g} Hz): t_s must be in seconds; in milliseconds "
        f"the samples would be at {rate_hz * 1e3:.3g} Hz, in microseconds at {rate_hz * 1e6:.3g} Hz"
    )


def csv_units(sensor: str) -> str:
    """What to check for a units finding (:mod:`mavattitude.sensors.unitcheck`) of a CSV: its columns' units."""
    return (
        "the CSV's acc_*_mps2 columns, read as m/s²" if sensor == "accelerometer" else "the CSV's mag_*_uT, read as µT"
    )


NAME = "solve"
HELP = "attitude for every sample of a CSV file (offline, same pipeline as the service)"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__.split("\n", 2)[2]
    parser.add_argument("input", help="input CSV (or .csv.gz) with t_s, acc_*_mps2, mag_*_uT [, gyr_*_radps]")
    parser.add_argument("-o", "--output", required=True, help="output CSV (gzip-compressed if it ends in .gz)")
    add_config_arguments(parser)
    parser.add_argument(
        "--save-mag-offset",
        metavar="OUT.yaml",
        help="with --method fused: write the magnetometer calibration with the hard-iron offset the filter learnt "
        "added (the `calibrate` format, to merge into the config)",
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help=f"progress on stderr (default: only for inputs of {PROGRESS_MIN_SAMPLES} samples or more)",
    )


def read_samples(path: str | Path) -> dict[str, np.ndarray]:
    """The solve columns of a CSV: ``t_s`` (N,), ``acc``, ``mag`` and, if present, ``gyr`` (N, 3)."""
    if Path(path).suffix.lower() in LOG_SUFFIXES:
        raise DataFileError(f"{path}: a flight log, not a CSV of samples: `mavattitude replay {path}` reads it")
    data = read_columns(path, (TIME_COLUMN, *ACC_COLUMNS, *MAG_COLUMNS), GYR_COLUMNS)
    if len(data[TIME_COLUMN]) == 0:
        raise DataFileError(f"{path}: no data rows")
    sensors = {"acc": ACC_COLUMNS, "mag": MAG_COLUMNS, "gyr": GYR_COLUMNS}  # gyr only where all three are there
    return {"t_s": data[TIME_COLUMN]} | {
        key: np.column_stack([data[c] for c in names]) for key, names in sensors.items() if set(names) <= data.keys()
    }


def check_offline_config(config: Config, has_gyro: bool, source: str) -> None:
    """What an offline run needs beyond a valid config."""
    if METHODS[config.estimator.method].needs_gyro and not has_gyro:
        raise ConfigError(
            f"estimator.method {config.estimator.method} needs a gyroscope, and {source} has no gyr_*_radps columns"
        )


def run(args: argparse.Namespace) -> int:
    from mavattitude.pipeline import AttitudePipeline
    from mavattitude.reports import rate_handling
    from mavattitude.sensors.frontend import median_rate_hz

    config = config_from_args(args)
    refuse_overwriting([args.input], args.output, args.save_mag_offset)
    data = read_samples(args.input)
    check_offline_config(config, "gyr" in data, args.input)
    if args.save_mag_offset and not METHODS[config.estimator.method].learns_mag_offset:
        raise ConfigError("--save-mag-offset needs --method fused: only the fused filter learns a hard-iron offset")
    pipeline = AttitudePipeline(config)
    t = data["t_s"]
    n = len(t)
    # Without gyro columns: zero rates (the snapshot solve does not use them, and the CSV output has none).
    gyr = data.get("gyr", np.zeros((n, 3)))
    wanted = n >= PROGRESS_MIN_SAMPLES if args.progress is None else args.progress
    progress = Progress(f"solve {Path(args.input).name}, output ticks", wanted)
    rate_hz = median_rate_hz(t)
    with about(args.input):
        if (hint := time_unit_hint(rate_hz)) is not None:
            log.warning("%s", hint)
        # every row its own magnetometer reading: the samples as push() takes them one by one, all at once
        pushed = pipeline.push_batch(t, data["acc"], gyr, data["mag"], np.ones(n, dtype=bool), progress=progress)
        summarise(pipeline, n, args.input, pushed.compass, csv_units)
        frontend = pipeline.counters.frontend
        log.info("%s", rate_handling(config, "samples", rate_hz, frontend.per_sample, n))
    write_outputs(args.output, pushed.outputs)
    log.info("wrote %d attitudes to %s", len(pushed.outputs), args.output)
    if args.save_mag_offset:
        save_mag_offset(args.save_mag_offset, config, pipeline.estimator.counters())
    return 0


def save_mag_offset(path: str, config: Config, counters: dict[str, float]) -> None:
    """The config's magnetometer calibration with the fused filter's learnt body-frame offset folded in."""
    from mavattitude.sensors.calibration import hard_iron_with_body_offset, mag_block
    from mavattitude.sensors.mounting import mounting_matrix

    offset = [counters.get(f"mag_offset_{axis}_uT", 0.0) for axis in "xyz"]  # none: the filter never started
    mag = config.calibration.mag
    hard_iron = hard_iron_with_body_offset(mag, mounting_matrix(config.mounting.rotation), offset)
    Path(path).write_text(
        "# magnetometer calibration with the hard-iron offset learnt by `mavattitude solve --method fused` "
        f"(body-frame offset {', '.join(f'{v:.2f}' for v in offset)} µT): mag = soft_iron (raw − hard_iron_uT)\n"
        + yaml.safe_dump(mag_block(hard_iron, mag.soft_iron), sort_keys=False),
        encoding="utf-8",
    )
    log.info("wrote the magnetometer calibration with the learnt offset to %s", path)
