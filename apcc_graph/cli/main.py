"""The entry point of ``apcc-graph``: the parser assembled from the subcommand modules, and
:func:`main`, which runs one and turns a user's mistake into one line on stderr and exit code 1
(``--debug`` shows the traceback instead)."""

from __future__ import annotations

import argparse
import os
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
from apcc_graph.cli.console import quiet_option
from apcc_graph.io.console import print_line
from apcc_graph.io.interrupts import catching_interrupts, check_interrupted

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
    quiet_option(parser)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in SUBCOMMANDS:
        module.add_parser(commands)
    return parser


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str,
                      lineno: int, file: object = None, line: str | None = None) -> None:
    """Warnings of the library as one line on stderr, like errors (above a progress bar or
    the live status line, never glued onto it)."""
    print_line(" ".join(f"apcc-graph: warning: {message}".split()), sys.stderr)


def error_line(exc: BaseException) -> str:
    """The one line ``apcc-graph`` prints for an exception (without the ``apcc-graph: error:``
    prefix): a user's mistake or an OS error as it is, a gtsam failure decoded (which variable,
    what to try), anything else as an internal error with a pointer to ``--debug``."""
    from apcc_graph.estimation.failures import gtsam_failure, is_gtsam_error

    if is_gtsam_error(exc):
        message = gtsam_failure(exc)
    elif isinstance(exc, UserError | ValueError | OSError):
        message = (str(exc) if not isinstance(exc, OSError) or not exc.filename
                   else f"{exc.filename}: {exc.strerror}")
    else:
        message = (f"internal error: {type(exc).__name__}: {exc} (run with --debug for the "
                   "traceback)")
    return " ".join(message.split())


def _forget_unhandled_interrupt() -> None:
    """Clear CPython's note that a ``KeyboardInterrupt`` went unhandled (set when one passes
    through code run by ``PyRun_String``, as some extension modules do, even if it is caught
    later): at exit it would kill the process by SIGINT instead of exiting with 130."""
    import ctypes

    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (AttributeError, ValueError, OSError):  # another interpreter: nothing to clear
        pass


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``apcc-graph``; returns the exit code: 0 done, 1 an error (one line on
    stderr), 130 interrupted (Ctrl-C; nothing half-written is left)."""
    debug = False
    try:
        with warnings.catch_warnings(), catching_interrupts(final=argv is None):
            warnings.showwarning = _one_line_warning
            args = build_parser().parse_args(argv)
            debug = args.debug
            try:
                result = args.run(args)
            except Exception:
                check_interrupted()  # Ctrl-C in compiled code can surface as another error
                raise
            check_interrupted()  # a Ctrl-C that a C callback swallowed
            print(result)
    except KeyboardInterrupt:
        if debug:
            raise
        print("apcc-graph: interrupted", file=sys.stderr)
        if argv is None:
            _forget_unhandled_interrupt()
        return 130
    except BrokenPipeError:  # the reader of stdout went away (e.g. `| head`)
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - no second error at exit
        return 1
    except Exception as exc:  # noqa: BLE001 - every failure is one line without --debug
        if debug:
            raise
        print(f"apcc-graph: error: {error_line(exc)}", file=sys.stderr)
        return 1
    return 0
