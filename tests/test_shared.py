"""The ../shared rule: absent, its tests skip with the reason (fail under CI); nothing cites it by hand."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests import shared

ROOT = Path(__file__).resolve().parents[1]


def test_absent_shared_skips_with_the_reason(monkeypatch, tmp_path) -> None:
    monkeypatch.setattr(shared, "SHARED_DIR", tmp_path / "shared")
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"needs shared/data/x\.csv: \.\./shared .* is not beside"):
        shared.shared_path("data", "x.csv")


def test_absent_shared_fails_under_ci(monkeypatch, tmp_path) -> None:
    monkeypatch.setattr(shared, "SHARED_DIR", tmp_path / "shared")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI is set"):
        shared.shared_path("data", "x.csv")


def test_present_shared_gives_the_path(monkeypatch, tmp_path) -> None:
    (tmp_path / "shared" / "data").mkdir(parents=True)
    (tmp_path / "shared" / "data" / "x.csv").write_text("t_s\n")
    monkeypatch.setattr(shared, "SHARED_DIR", tmp_path / "shared")
    monkeypatch.setenv("CI", "true")
    assert shared.shared_path("data", "x.csv") == tmp_path / "shared" / "data" / "x.csv"


def test_tests_reach_shared_only_through_the_helper() -> None:
    # A path built by hand would fail with FileNotFoundError in a clone without ../shared.
    by_hand = re.compile(r"""["']shared["']|["']\.\./shared/""")
    offenders = [
        str(p.relative_to(ROOT))
        for p in (ROOT / "tests").rglob("*.py")
        if p.name not in ("shared.py", "test_shared.py") and by_hand.search(p.read_text(encoding="utf-8"))
    ]
    assert offenders == []


def test_docs_and_docstrings_cite_nothing_outside_the_project() -> None:
    cited = re.compile(r"shared/paper|NOTES\.md")
    files = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "mavattitude").rglob("*.py")]
    files += [*(ROOT / "tools").glob("*.py"), *(ROOT / "tests").rglob("*.py")]
    offenders = [str(p.relative_to(ROOT)) for p in files if p != Path(__file__) and cited.search(p.read_text("utf-8"))]
    assert offenders == []
