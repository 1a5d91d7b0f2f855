"""The command line at its edges (tests/edge_matrix.py): every odd or bad input a user has met,
through the installed ``apcc-graph`` in a subprocess: refused in one line, warned about by name,
or accepted whole; never a traceback, a silent accept or a half-written output.
``python tests/edge_matrix.py`` prints the same cases with their counts."""

from __future__ import annotations

from pathlib import Path

import pytest
from edge_matrix import CASES, run_case


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_the_command_line_at_its_edges(case, tmp_path: Path) -> None:  # noqa: ANN001
    outcome = run_case(case, tmp_path)
    assert outcome.problems == [], outcome.stderr
