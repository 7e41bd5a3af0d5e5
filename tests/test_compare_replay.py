"""tools/compare_replay.py: which package each side runs, and what counts as a difference between two replays."""

from __future__ import annotations

import shutil

import numpy as np

from mavattitude.cli import main
from mavattitude.sim.logwriter import static_log, write_dataflash
from tests.tools import ROOT, load_tool

compare_replay = load_tool("compare_replay")
REF = ["--declination", "0", "--inclination", "63.5", "--no-plot"]


def test_python_m_imports_the_package_of_the_directory_it_starts_in(tmp_path):
    """Why the base runs from its own worktree: started in a directory holding a mavattitude package, ``python -m``
    imports that one, whatever PYTHONPATH says; elsewhere, the installed (here: editable) checkout's."""
    (tmp_path / "mavattitude").mkdir()
    (tmp_path / "mavattitude" / "__init__.py").write_text("")
    assert compare_replay._package_dir(tmp_path) == tmp_path / "mavattitude"
    assert compare_replay._package_dir(ROOT) == ROOT / "mavattitude"


def test_identical_replays_are_identical_and_a_turned_attitude_is_measured(tmp_path):
    log = write_dataflash(tmp_path / "f.bin", static_log(2.0, yaw_rate_dps=10.0))
    for side in ("base", "new"):
        assert main(["replay", str(log), "-o", str(tmp_path / side), *REF]) == 0
    assert compare_replay.compare(tmp_path / "base", tmp_path / "new") == []  # the summaries name their own dirs

    path = tmp_path / "new" / "f.csv"
    rows = np.genfromtxt(path, delimiter=",", names=True)
    half = 0.5e-3  # rad: qw, qz of a yaw turned by 1e-3 rad more
    c, s = np.cos(half), np.sin(half)
    rows["qw"], rows["qz"] = rows["qw"] * c - rows["qz"] * s, rows["qw"] * s + rows["qz"] * c
    np.savetxt(path, rows, delimiter=",", header=",".join(rows.dtype.names), comments="", fmt="%.12g")
    shutil.copy(tmp_path / "new" / "f.csv", tmp_path / "new" / "g.csv")
    found = compare_replay.compare(tmp_path / "base", tmp_path / "new")
    assert found[0].startswith("f.csv: differs, by 0.001 rad at most"), found
    assert found[1:] == ["g.csv: written by this checkout only"]
