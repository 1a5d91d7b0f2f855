"""The ``apcc-graph`` command line: one module per subcommand (its parser and its run function:
:mod:`~apcc_graph.cli.calibrate`, :mod:`~apcc_graph.cli.simulate`,
:mod:`~apcc_graph.cli.track`, :mod:`~apcc_graph.cli.estimate`,
:mod:`~apcc_graph.cli.evaluate`, :mod:`~apcc_graph.cli.plot`, :mod:`~apcc_graph.cli.bench`),
the options and checks they share (:mod:`~apcc_graph.cli.common`) and the entry point
(:mod:`~apcc_graph.cli.main`).

May import: every layer of apcc_graph. Nothing below imports it.
"""

from apcc_graph.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
