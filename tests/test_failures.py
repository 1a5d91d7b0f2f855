"""gtsam's failures in the user's words (apcc_graph.estimation.failures): graph keys decoded into
what they stand for, and only gtsam's own errors taken for gtsam's."""

from __future__ import annotations

import gtsam
import pytest

from apcc_graph.estimation.failures import gtsam_failure, is_gtsam_error
from apcc_graph.factors.keys import describe


@pytest.mark.parametrize("key, name", [
    (gtsam.symbol("x", 42), "frame 42's bends"),
    (gtsam.symbol("t", 7 * 64 + 2), "frame 7's segment 3 tip"),
    (gtsam.symbol("l", 1 * 2**32 + 905), "camera 2's point 905"),
    (gtsam.symbol("c", 0), "segment 1's k and delta_max"),
    (gtsam.symbol("m", 2), "camera 3's mount"),
    (gtsam.symbol("p", 9 * 64 + 1), "frame 9's camera 2 pose"),
    (gtsam.symbol("q", 5), "variable q5"),
])
def test_a_key_is_named_for_what_it_stands_for(key: int, name: str) -> None:
    assert describe(key) == name


def test_a_gtsam_error_is_one_line_naming_its_variable() -> None:
    key = gtsam.symbol("x", 17)
    error = RuntimeError(f"\nIndeterminant linear system detected while working near "
                         f"variable\n{key} (Symbol: x17).\n\nThoughout this ...")
    assert is_gtsam_error(error)
    line = gtsam_failure(error)
    assert "\n" not in line
    assert line.startswith("gtsam failed near frame 17's bends: an indeterminate linear system")


@pytest.mark.parametrize("error", [
    ValueError("new_gtsam_smoother: the lag must be positive"),
    RuntimeError("gtsam is not installed for this Python"),
    KeyError("indeterminate linear system"),  # gtsam's words, but not an error gtsam raises
])
def test_the_library_s_own_errors_are_not_taken_for_gtsam_s(error: BaseException) -> None:
    assert not is_gtsam_error(error)
