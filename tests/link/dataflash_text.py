"""A binary DataFlash log written out as text, as Mission Planner converts a .bin to a .log: every record read
back with pymavlink's DFReader (the reference reader), one line each, ``NAME, v1, v2, …``, CRLF; floats as
.NET prints them, a float32 field to 7 significant digits, a scaled integer (``c``, ``L``: lat/lon 1e-7 °)
with every digit it has."""

from __future__ import annotations

from pathlib import Path

from pymavlink import DFReader


def _value(value: object, char: str) -> str:
    if isinstance(value, float):
        return f"{value:.7g}" if char == "f" else repr(value)
    return str(value)


def write_text_log(binary: Path, text: Path) -> Path:
    df = DFReader.DFReader_binary(str(binary), zero_time_base=False)
    lines = []
    while (msg := df.recv_msg()) is not None:
        if msg.get_type() == "FMT":
            lines.append(f"FMT, {msg.Type}, {msg.Length}, {msg.Name}, {msg.Format}, {msg.Columns}")
            continue
        fmt = msg.fmt
        values = (_value(getattr(msg, c), char) for c, char in zip(fmt.columns, fmt.format, strict=True))
        lines.append(", ".join([msg.get_type(), *values]))
    text.write_bytes(("\r\n".join(lines) + "\r\n").encode("ascii"))
    return text
