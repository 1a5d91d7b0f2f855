"""gtsam's failures in the user's words: the variable a gtsam error names by its key (a
number such as ``8646911284551352362``) decoded into what it stands for (frame 42's bends, a
segment tip, a track's point, a calibrated model or mount), and what to try."""

from __future__ import annotations

import re

from apcc_graph.factors.keys import describe

GTSAM_SIGNS = ("indeterminant linear system", "indeterminate linear system", "variableindex",
               "cheirality", "key does not exist", "valueskeydoesnotexist",
               "valuesincorrecttype", "not positive definite")
"""Phrases that mark an exception's message as gtsam's (gtsam raises plain ``RuntimeError``
and ``ValueError``). The word "gtsam" alone is not one: the library's own messages name
gtsam too, and must reach the user as they are."""

_KEY = re.compile(r"\b\d{15,20}\b")
def is_gtsam_error(error: BaseException) -> bool:
    """Whether ``error`` comes from gtsam (judged by its message)."""
    text = str(error).lower()
    return isinstance(error, RuntimeError | ValueError) and any(s in text for s in GTSAM_SIGNS)


def _what_and_hint(text: str) -> tuple[str, str]:
    """What went wrong in gtsam's message ``text``, and what to try."""
    lower = text.lower()
    if "indeterminant linear system" in lower or "indeterminate linear system" in lower:
        return ("an indeterminate linear system (the images and priors do not fix the "
                "variable)", "check the robot file's cameras (intrinsics, distortion, mounts) "
                "and the tracks; with --method smoother try --factorization QR or a longer --lag")
    if "variableindex" in lower:
        return ("its variable index went inconsistent",
                "run it again; if it repeats, try another --method")
    return text[:200], "check the robot file and the tracks, or try another --method"


def _near(text: str) -> str:
    """`` near <the variable>`` for the first graph key in ``text``, or nothing."""
    keys = [int(k) for k in _KEY.findall(text)]
    return f" near {describe(keys[0])}" if keys else ""


def gtsam_cause(error: BaseException) -> str:
    """A gtsam error in a few words, its variable decoded (e.g. ``an indeterminate linear
    system near frame 42's bends``), for a warning that goes on."""
    text = " ".join(str(error).split())
    what = _what_and_hint(text)[0].split(" (")[0]
    return what + _near(text)


def gtsam_failure(error: BaseException) -> str:
    """A gtsam error as one line: what failed, near which variable (decoded), what to try."""
    text = " ".join(str(error).split())
    what, hint = _what_and_hint(text)
    return f"gtsam failed{_near(text)}: {what}; {hint}"
