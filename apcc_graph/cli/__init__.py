"""The ``apcc-graph`` command line: one module per subcommand (its parser and its run function),
the options they share (:mod:`~apcc_graph.cli.common`) and the entry point
(:mod:`~apcc_graph.cli.main`).

May import: every layer of apcc_graph. Nothing below imports it.
"""

from apcc_graph.cli.main import main

__all__ = ["main"]
