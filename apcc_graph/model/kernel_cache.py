"""Where the compiled numba kernels are kept between processes, and ``njit`` itself.

Every kernel module (``factors/*_jit.py``, ``frontend/*_jit.py``) takes ``njit`` from here and
says ``cache=True``: the first process compiles a kernel and writes it to disk, later ones load
it (a fraction of a second instead of seconds per kernel). numba keeps the compiled code in the
``__pycache__`` folder beside the kernel's source file or, when that is not writable (an
install into a read-only ``site-packages``), in the user's cache folder (``~/.cache/numba``).
When neither is writable numba refuses to decorate a cached kernel at all, and the package
would not import; then, unless ``NUMBA_CACHE_DIR`` says where, the kernels go to a folder of
their own in the temporary directory (:func:`ensure_cache_dir`): ``apcc-graph-numba-<uid>``
when it is a real folder of the user's with mode 0700 (made so when missing), else a new
folder of this process's own (a symbolic link, another user's folder or one others can write
to is never used: the cache's index is a pickle). A kernel's cache is keyed by
its source file's contents: editing the file compiles it again, once.
"""

from __future__ import annotations

import os
import stat
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
    uid = os.getuid() if hasattr(os, "getuid") else None
    folder = Path(tempfile.gettempdir()) / f"apcc-graph-numba-{uid}"
    if uid is None or not _private(folder, uid):
        folder = Path(tempfile.mkdtemp(prefix="apcc-graph-numba-"))  # this process's own
    config.CACHE_DIR = str(folder)
    return config.CACHE_DIR


def _private(folder: Path, uid: int) -> bool:
    """Whether ``folder`` is (or was just made) a real folder of user ``uid`` that only it
    can read, write or enter (mode 0700): numba's cache index is a pickle, loaded as code, so a
    folder another user made or can write to is never used."""
    try:
        folder.mkdir(mode=0o700)
        os.chmod(folder, 0o700)  # ours: whatever the umask took away
    except FileExistsError:
        pass
    except OSError:
        return False
    try:
        info = os.lstat(folder)
    except OSError:
        return False
    return (stat.S_ISDIR(info.st_mode) and info.st_uid == uid
            and stat.S_IMODE(info.st_mode) == 0o700)


ensure_cache_dir()
