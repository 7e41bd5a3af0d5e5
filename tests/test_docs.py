"""The docs answer the first questions, and what they state is what the code does."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

from mavattitude.cli import build_parser
from mavattitude.sensors.magref import field_from_angles

ROOT = Path(__file__).resolve().parents[1]
FRAMES = ROOT / "docs" / "frames.md"


def test_the_readme_says_which_north_and_links_the_frames_doc() -> None:
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("### Frames, north and declination") :]
    section = section[: section.index("\n#")]
    assert "true north" in section and "magnetic north" in section and "(docs/frames.md)" in section


def test_the_frames_doc_covers_north_signs_lookup_and_auto() -> None:
    headings = re.findall(r"^## (.+)$", FRAMES.read_text(), re.M)
    assert headings == [
        "Frames and angles",
        "Which north",
        "Sign conventions",
        "Where to look them up",
        "What `auto` does",
    ]


def test_the_worked_example_is_what_the_code_computes() -> None:
    text = FRAMES.read_text()
    d, i, f = (
        float(re.search(rf"`{k}: ([-\d.]+)`", text).group(1))
        for k in ("declination_deg", "inclination_deg", "intensity_uT")
    )  # type: ignore[union-attr]
    expected = "[" + ", ".join(f"{v:.2f}" for v in field_from_angles(d, i, f)) + "]"
    assert f"`field_ned_uT: {expected}`" in text  # sign conventions: east and down positive


def test_the_commands_the_frames_doc_shows_parse() -> None:
    parser = build_parser()
    for line in re.findall(r"^mavattitude (.+?)(?:\s+#.*)?$", FRAMES.read_text(), re.M):
        parser.parse_args(shlex.split(line))
