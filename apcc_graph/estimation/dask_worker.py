"""Set-up of every worker process of the local Dask cluster that runs many sequences (a Dask
preload: Dask imports this module in each worker and calls :func:`dask_setup`).

Ctrl-C at a terminal reaches every process of its group, the workers included: each would
print a traceback of its own. The workers ignore it; the process that started the cluster is
interrupted, says so in one line, and shuts the cluster down."""

from __future__ import annotations

import signal
import threading
from typing import Any


def dask_setup(worker: Any) -> None:
    """Make the worker process ignore SIGINT (Ctrl-C)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
