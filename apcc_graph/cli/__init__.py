"""The ``apcc-graph`` command line: one module per subcommand (its parser and its run function:
:mod:`~apcc_graph.cli.calibrate`, :mod:`~apcc_graph.cli.simulate`,
:mod:`~apcc_graph.cli.track`, :mod:`~apcc_graph.cli.estimate`,
:mod:`~apcc_graph.cli.evaluate`, :mod:`~apcc_graph.cli.plot`, :mod:`~apcc_graph.cli.bench`),
the options and checks they share (:mod:`~apcc_graph.cli.common`) and the entry point
(:mod:`~apcc_graph.cli.main`).

May import: every layer of apcc_graph. Nothing below imports it.
"""

import signal as _signal
import sys as _sys
import threading as _threading

_interrupted: list[bool] = []


def _interrupted_while_starting(signum: int, frame: object) -> None:
    """Ctrl-C while the command's modules load: noted, and acted on once they are loaded
    (raised inside a module's initialisation, it would break that import with a traceback)."""
    _interrupted.append(True)


# the modules take a second or two to load: a Ctrl-C then is one line too, not a traceback
_starting = _threading.current_thread() is _threading.main_thread() and (
    _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler)
# the command itself (its console script, or python -m apcc_graph.cli), not a program that
# imports it: Ctrl-C stays recorded until main() takes over, and main() then acts on it
_command = _sys.argv[0] == "-m" or _sys.argv[0].replace("\\", "/").rsplit("/", 1)[-1] in (
    "apcc-graph", "apcc-graph.exe", "apcc-graph-script.py")
if _starting:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
try:
    from apcc_graph.cli.main import build_parser, main
    from apcc_graph.io.interrupts import record_early_interrupt as _record
finally:
    if _starting:
        _signal.signal(_signal.SIGINT, _record if _command and "_record" in globals()
                       else _signal.default_int_handler)
if _interrupted:
    print("apcc-graph: interrupted", file=_sys.stderr)
    raise SystemExit(130)

__all__ = ["build_parser", "main"]
