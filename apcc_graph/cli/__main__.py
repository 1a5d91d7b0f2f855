"""``python -m apcc_graph.cli``: the ``apcc-graph`` command."""

import sys

from apcc_graph.cli.main import main

sys.exit(main())
