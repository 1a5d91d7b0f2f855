"""The entry point of ``apcc-graph``: the parser assembled from the subcommand modules, and
:func:`main`, which runs one and turns a user's mistake into one line on stderr and exit code 1
(``--debug`` shows the traceback instead)."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence

from apcc_graph import __version__
from apcc_graph.cli import (
    bench,
    calibrate,
    estimate,
    evaluate,
    live,
    montecarlo,
    plot,
    robot,
    simulate,
    track,
)
from apcc_graph.cli.common import Parser, UserError

SUBCOMMANDS = (calibrate, simulate, track, estimate, live, evaluate, montecarlo, plot, robot,
               bench)
"""The modules of the subcommands, in the order ``--help`` lists them."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``apcc-graph`` (subcommands and their options)."""
    parser = Parser(
        prog="apcc-graph",
        description="Continuum-robot shape from tip cameras (APCC 2L-5R).",
    )
    parser.add_argument("--version", action="version", version=f"apcc-graph {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in SUBCOMMANDS:
        module.add_parser(commands)
    return parser


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str,
                      lineno: int, file: object = None, line: str | None = None) -> None:
    """Warnings of the library as one line on stderr, like errors."""
    print(f"apcc-graph: warning: {message}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``apcc-graph``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line_warning
            print(args.run(args))
    except (UserError, ValueError, OSError) as exc:
        if args.debug:
            raise
        message = (
            str(exc)
            if not isinstance(exc, OSError) or not exc.filename
            else (f"{exc.filename}: {exc.strerror}")
        )
        print(f"apcc-graph: error: {message}", file=sys.stderr)
        return 1
    return 0
