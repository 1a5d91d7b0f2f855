"""Test-wide settings: every property test draws its examples from a fixed seed, so a run on one
machine is the run on every other (a failure is reproduced by running the test again)."""

from __future__ import annotations

from hypothesis import settings

settings.register_profile("seeded", derandomize=True, print_blob=True)
settings.load_profile("seeded")
