"""Paths into ``../shared`` (real recordings and the paper), beside the project and never inside it.

A clone placed elsewhere has no ``../shared``: the tests that need it skip with one reason saying so, and
the rest of the suite passes without it. CI always has it, so there (``CI`` set in the environment) its
absence fails those tests instead: nothing is silently skipped where it matters.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED_DIR = Path(__file__).resolve().parents[1].parent / "shared"


def shared_path(*parts: str) -> Path:
    """``../shared/<parts>``; skip the calling test when it is absent, or fail it when ``CI`` is set.

    Call it inside a test or fixture (not at import), so only the tests that need the file are affected.
    """
    path = SHARED_DIR.joinpath(*parts)
    if path.exists():
        return path
    needed = path.relative_to(SHARED_DIR.parent)
    reason = f"needs {needed}: ../shared (real recordings, the paper) is not beside this clone"
    if os.environ.get("CI"):
        pytest.fail(f"{reason}, and CI is set (CI always has it)", pytrace=False)
    pytest.skip(reason)
