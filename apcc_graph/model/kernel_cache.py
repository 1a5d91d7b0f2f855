"""Where the compiled numba kernels are kept between processes, and ``njit`` itself.

Every kernel module (``factors/*_jit.py``, ``frontend/*_jit.py``) takes ``njit`` from here and
says ``cache=True``: the first process compiles a kernel and writes it to disk, later ones load
it (a fraction of a second instead of seconds per kernel). numba keeps the compiled code in the
``__pycache__`` folder beside the kernel's source file or, when that is not writable (an
install into a read-only ``site-packages``), in the user's cache folder (``~/.cache/numba``).
When neither is writable numba refuses to decorate a cached kernel at all, and the package
would not import; then, unless ``NUMBA_CACHE_DIR`` says where, the kernels go to a folder of
their own in the temporary directory (:func:`ensure_cache_dir`). A kernel's cache is keyed by
its source file's contents: editing the file compiles it again, once.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from numba import njit
from numba.core import config

__all__ = ["ensure_cache_dir", "njit"]

PACKAGE = Path(__file__).resolve().parents[1]


def _writable(folder: Path) -> bool:
    """Whether files can be made in ``folder`` (or in its nearest existing parent)."""
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return os.access(folder, os.W_OK | os.X_OK)


def _user_cache() -> Path:
    """numba's user-wide cache folder."""
    from numba.misc.appdirs import AppDirs

    return Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)


def ensure_cache_dir() -> str | None:
    """Point numba at a writable cache folder when neither the package's ``__pycache__``
    folders nor the user's cache folder is writable and ``NUMBA_CACHE_DIR`` is not set;
    returns the folder chosen then, else ``None`` (numba's own choice stands)."""
    if config.CACHE_DIR or _writable(PACKAGE) or _writable(_user_cache()):
        return None
    folder = Path(tempfile.gettempdir()) / f"apcc-graph-numba-{getattr(os, 'getuid', int)()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    config.CACHE_DIR = str(folder)
    return config.CACHE_DIR


ensure_cache_dir()
