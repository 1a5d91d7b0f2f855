"""Test-wide settings: every property test draws its examples from a fixed seed, so a run on one
machine is the run on every other (a failure is reproduced by running the test again); the
fixtures several test files share."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from hypothesis import settings

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "planar_three"

settings.register_profile("seeded", derandomize=True, print_blob=True)
settings.load_profile("seeded")


@pytest.fixture
def sample_copy(tmp_path: Path) -> Path:
    """A copy of the shipped sample sequence (without images) to change in a test."""
    folder = tmp_path / "seq"
    shutil.copytree(SAMPLE, folder, ignore=shutil.ignore_patterns("images"))
    return folder
