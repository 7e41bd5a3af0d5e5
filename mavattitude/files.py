"""The user's input files: opened and read so that a damaged or mistaken one is one DataFileError naming it.

Gzip (a name ending in .gz) is read transparently; a CSV row that is not numbers is reported with the file's
own line number, as an editor shows it.
"""

from __future__ import annotations

import csv
import gzip
import os
import warnings
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import numpy as np

from mavattitude.errors import DataFileError

#: The columns of the project's CSV of SI samples (``solve``'s input, the validation recordings,
#: ``calibrate``'s magnetometer input): the vehicle time and each sensor's three body axes.
TIME_COLUMN = "t_s"
ACC_COLUMNS = ("acc_x_mps2", "acc_y_mps2", "acc_z_mps2")
GYR_COLUMNS = ("gyr_x_radps", "gyr_y_radps", "gyr_z_radps")
MAG_COLUMNS = ("mag_x_uT", "mag_y_uT", "mag_z_uT")
LOG_SUFFIXES = (".tlog", ".bin", ".ulg", ".log")  # the flight logs replay and calibrate read (told apart by content)


def open_text(path: str | Path, mode: str) -> IO[str]:
    """A text file, gzip-compressed when its name ends in .gz; UTF-8, read with or without the byte-order mark a
    spreadsheet's "CSV UTF-8" export begins with."""
    path = Path(path)
    encoding = "utf-8-sig" if "r" in mode else "utf-8"
    try:
        if path.suffix == ".gz":
            return gzip.open(path, mode + "t", encoding=encoding, newline="")  # type: ignore[return-value]
        return path.open(mode, encoding=encoding, newline="")
    except OSError as exc:
        raise DataFileError(f"{path}: cannot open: {exc.strerror or exc}") from exc


def refuse_overwriting(inputs: Sequence[str | Path], *outputs: str | Path | None) -> None:
    """A DataFileError when an output is one of the inputs (the same file under any name): writing the results
    would destroy the recording they come from."""
    for output in (o for o in outputs if o is not None and Path(o).exists()):
        for given in inputs:
            if Path(given).exists() and os.path.samefile(output, given):
                raise DataFileError(f"{output}: that is the input {given}; the results would overwrite it")


@contextmanager
def reading(path: str | Path) -> Iterator[None]:
    """What a damaged or mistaken input file raises while it is read, as one DataFileError naming it."""
    try:
        yield
    except gzip.BadGzipFile:
        raise DataFileError(f"{path}: not gzip-compressed, though its name ends in .gz") from None
    except (EOFError, zlib.error) as exc:
        raise DataFileError(f"{path}: truncated or corrupt gzip data ({exc})") from None
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    except csv.Error as exc:
        raise DataFileError(f"{path}: not a CSV file ({exc})") from None


def first_bad_row(path: str | Path, columns: Sequence[int]) -> str:
    """``PATH:LINE: what is wrong`` for the first data row whose ``columns`` are not all numbers.

    LINE is the file's own line number (the header is line 1, blank lines count), which numpy's row index
    (0-based, over data rows, blank lines skipped) is not.
    """
    with reading(path), open_text(path, "r") as f:
        reader = csv.reader(f)
        header = next(reader, [])
        for row in reader:
            if not row:
                continue
            if len(row) <= max(columns):
                return f"{path}:{reader.line_num}: {len(row)} field(s), the header has more"
            for i in columns:
                if not _is_number(row[i]):
                    what = f"{row[i]!r} is not a number" if row[i].strip() else "empty (write nan for a missing value)"
                    name = header[i].strip() if i < len(header) else f"{i + 1}"  # a header line left empty
                    return f"{path}:{reader.line_num}: column {name}: {what}"
    return f"{path}: not a numeric CSV"


def _separator_hint(header: Sequence[str]) -> str:
    """What to change when a header is one field separated otherwise (a spreadsheet's ';' where the decimal
    mark is a comma, or tabs)."""
    other = next((sep for sep in (";", "\t") if len(header) == 1 and sep in header[0]), None)
    return f"; columns are separated by commas, and this header by {other!r}" if other else ""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def load_numbers(f: IO[str], path: str | Path, usecols: Sequence[int]) -> np.ndarray:
    """The rest of an open CSV ``f`` as an (N, len(usecols)) array; a row that is not numbers is a
    DataFileError with its line; no rows at all is an empty array (numpy's warning about it is not shown)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return np.loadtxt(f, delimiter=",", usecols=usecols, ndmin=2)
    except ValueError:
        raise DataFileError(first_bad_row(path, usecols)) from None


def read_columns(path: str | Path, required: Sequence[str], optional: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """The named columns of a CSV of numbers, by its header: every ``required`` one (those missing are one
    DataFileError naming them) and those of ``optional`` that it has."""
    with reading(path), open_text(path, "r") as f:
        header = [name.strip() for name in next(csv.reader([f.readline()]), [])]
        missing = [c for c in required if c not in header]
        if missing:
            raise DataFileError(
                f"{path}: missing column(s) {', '.join(missing)} (header: {', '.join(header)[:200]})"
                + _separator_hint(header)
            )
        names = [*required, *(c for c in optional if c in header)]
        data = load_numbers(f, path, [header.index(c) for c in names])
    return {name: data[:, i] for i, name in enumerate(names)}
