"""The command line's ``--quiet`` option (:mod:`apcc_graph.io.console` draws the bars)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from apcc_graph.io.console import set_quiet


class QuietOption(argparse.Action):
    """``--quiet``: no progress bars and no live status line (warnings and errors stay)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.setdefault("help", "no progress bars or status line on stderr (they are drawn "
                          "only on a terminal anyway); warnings and errors are still printed")
        super().__init__(option_strings, dest, nargs=0, default=False, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        setattr(namespace, self.dest, True)
        set_quiet(True)


def quiet_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--quiet`` to ``parser`` (and forget an earlier parse's)."""
    set_quiet(False)
    parser.add_argument("--quiet", action=QuietOption)
