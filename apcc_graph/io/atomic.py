"""Write files atomically: a temporary file in the same folder, then ``os.replace``.

A reader never sees a half-written file, and an error while writing leaves the previous file (if
any) untouched. The file ends with the permissions an ordinary ``open(path, "w")`` gives
(``0o666`` less the process's umask), not the owner-only ``0o600`` of a temporary file, so
what is written can be shared.
"""

from __future__ import annotations

import errno
import os
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

from apcc_graph.io.interrupts import check_interrupted

_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process's umask, read without changing it for other threads (from
    ``/proc/self/status`` where there is one, else set and restored under a lock)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """The permission bits of a new file: ``0o666`` less the umask."""
    return 0o666 & ~current_umask()


def folder_mode() -> int:
    """The permission bits of a new folder: ``0o777`` less the umask."""
    return 0o777 & ~current_umask()


def write_error(exc: OSError, path: str | Path) -> OSError:
    """``exc`` said of ``path`` (the destination, not a temporary name), in the words the
    command line prints: ``<path>: no space left on device; ...``."""
    reason = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        reason = "no space left on device"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        reason = f"cannot write ({reason[:1].lower() + reason[1:]})"
    else:
        reason = f"cannot write ({reason})"
    return OSError(exc.errno, f"{reason}; nothing was written there", str(path))


@contextmanager
def atomic_file(path: str | Path) -> Iterator[BinaryIO]:
    """A binary file handle whose contents replace ``path`` only when the block ends without
    an error (creating the parent folder if needed); on an error, or Ctrl-C, the temporary
    file is removed and ``path`` is untouched.

    Raises:
        OSError: writing failed (the message names ``path``; see :func:`write_error`).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise write_error(exc, path) from exc
    try:
        os.fchmod(fd, file_mode())
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        check_interrupted()
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise write_error(exc, path) from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, creating the parent folder if needed.

    Args:
        path: destination file.
        data: the complete contents.

    Raises:
        OSError: writing failed (a full disk, no permission); ``path`` is untouched and the
            message names it.
    """
    with atomic_file(path) as handle:
        handle.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, text.encode("utf-8"))
