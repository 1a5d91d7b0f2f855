"""Output folders written whole: everything goes into a hidden staging folder beside the
destination (``.NAME.partial-<random>`` in the same parent), which is renamed into place only when
complete. A failure, a full disk or Ctrl-C removes the staging folder and leaves the
destination as it was; with ``replace`` an existing destination is swapped out only at the end
(renamed aside, the new one renamed in, the old one deleted), so the old and the new never mix.

A destination that exists and is empty (a folder, a symlink to one, a mount point, a folder
whose parent cannot be written) is kept as it is, with its owner, mode and ACLs: the staging
folder is then made inside it (``.apcc-graph.partial-<random>``), and its contents are moved up
into it when complete. A symlink to a folder stays a symlink: the folder it points to is
written (or replaced), as above.

Before any computing, :func:`check_writable` tells whether a destination can be written at all.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from apcc_graph.io.atomic import folder_mode, write_error
from apcc_graph.io.interrupts import check_interrupted, deferring_interrupts

STAGING = ".partial-"
"""What the name of a staging folder holds (``.NAME.partial-<random>``)."""

INSIDE = f".apcc-graph{STAGING}"
"""The name of a staging folder inside an empty destination (``.apcc-graph.partial-<random>``)."""


def staging_folders(destination: str | Path) -> list[Path]:
    """The staging folders of ``destination`` left in its parent or inside it (by a process
    that was killed before it could remove them)."""
    destination = Path(destination)
    beside = (sorted(destination.parent.glob(f".{destination.name}{STAGING}*"))
              if destination.parent.is_dir() else [])
    inside = sorted(destination.glob(f"{INSIDE}*")) if destination.is_dir() else []
    return beside + inside


def _followed(path: Path) -> Path:
    """The folder a symlink ``path`` points to (which is then written, the link kept), else
    ``path``."""
    return path.resolve() if path.is_symlink() and path.is_dir() else path


def _is_empty_folder(path: Path) -> bool:
    """Whether ``path`` is an existing folder (or a symlink to one) that holds nothing."""
    try:
        return path.is_dir() and not any(path.iterdir())
    except OSError:
        return False


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest ancestor that exists."""
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(path: str | Path, folder: bool = True) -> Path:
    """Whether ``path`` (a folder, or a file when not ``folder``) can be written: not an
    existing file where a folder is expected (nor the reverse), and its parent exists or can be
    created, is a folder and takes a new file (tried with a probe file: permission bits alone do
    not tell, e.g. for root or on a read-only mount).

    Raises:
        OSError: why not, naming ``path`` or the ancestor that refuses.
    """
    path = Path(path)
    if folder and path.exists() and not path.is_dir():
        raise OSError(f"{path}: is a file, expected a folder to write into")
    if not folder and path.is_dir():
        raise OSError(f"{path}: is a folder, not a file")
    # an empty folder is written into (see staged_folder), any other beside (the folder a
    # symlink points to: beside that)
    target = _followed(path.absolute()) if folder else path
    parent = target if folder and _is_empty_folder(target) else _nearest_existing(
        target.parent)
    if not parent.is_dir():
        raise OSError(f"{path}: cannot be created: {parent} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".apcc-graph-probe-", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise OSError(f"{path}: cannot be written: no new file can be made in {parent} "
                      f"({reason[:1].lower() + reason[1:]})") from None
    return path


def replace_refusal(path: str | Path, inputs: Sequence[str | Path] = ()) -> str | None:
    """Why the existing folder ``path`` must not be replaced whole (``--force``), or ``None``
    when it may: it is a mount point that holds something (it cannot be renamed), is or holds
    the current folder, is the home folder, or is or holds one of ``inputs`` (a replaced
    folder is deleted). The message follows ``path``'s name."""
    resolved, here = Path(path).resolve(), Path.cwd().resolve()
    if os.path.ismount(resolved) and not _is_empty_folder(resolved):
        return ("is a mount point, which cannot be replaced whole (only written into when "
                "empty): empty it")
    if resolved in (here, *here.parents, Path.home().resolve()):
        return ("--force would replace this folder whole, and it holds the current folder "
                "(or is your home)")
    for given in inputs:
        source = Path(given).resolve()
        if resolved == source or resolved in source.parents:
            return f"holds the input {given}; --force would replace it with the output"
    return None


def _remove(path: Path) -> None:
    """Delete a folder tree, ignoring what is already gone."""
    shutil.rmtree(path, ignore_errors=True)


@contextmanager
def staged_folder(destination: str | Path, replace: bool = False) -> Iterator[Path]:
    """A new, empty staging folder for ``destination``; when the block ends without an error
    it becomes ``destination``. On any error or Ctrl-C the staging folder is deleted and
    ``destination`` is untouched.

    Args:
        destination: the output folder.
        replace: an existing ``destination`` (a folder) is replaced whole; without it, only an
            empty one is.

    Raises:
        OSError: the staging folder could not be made or moved into place (the message names
            ``destination``), or ``destination`` holds something and ``replace`` is not given.
    """
    given = Path(os.path.abspath(destination))  # "." and ".." have no name to stage
    destination = _followed(given)
    inside = _is_empty_folder(destination)  # kept as it is (owner, mode, a symlink, a mount)
    try:
        if inside:
            staging = Path(tempfile.mkdtemp(prefix=INSIDE, dir=destination))
        else:
            destination.parent.mkdir(parents=True, exist_ok=True)
            staging = Path(tempfile.mkdtemp(prefix=f".{destination.name}{STAGING}",
                                            dir=destination.parent))
        os.chmod(staging, folder_mode())
    except OSError as exc:
        raise write_error(exc, given) from exc
    try:
        yield staging
        check_interrupted()
        if inside:
            _move_up(staging, destination)
        else:
            _swap_in(staging, destination, replace)
    except OSError as exc:
        _remove(staging)
        if exc.filename is not None and str(exc.filename).startswith(str(staging)):
            # name the file as it would be in the destination, not in the staging folder
            inside = Path(exc.filename).relative_to(staging)
            raise OSError(exc.errno, exc.strerror, str(given / inside)) from exc
        if str(staging) in str(exc):  # a message that names a file in its own words
            raise OSError(str(exc).replace(str(staging), str(given))) from exc
        raise
    except BaseException:
        _remove(staging)
        raise


def _move_up(staging: Path, destination: Path) -> None:
    """Move the contents of the complete ``staging`` folder up into ``destination`` (its
    parent, empty when the staging began), all of them or none, and remove ``staging``."""
    appeared = sorted(p.name for p in destination.iterdir() if p != staging)
    if appeared:
        raise OSError(f"{destination}: {appeared[0]} appeared in it while writing; the new "
                      "output was not written")
    moved: list[str] = []
    with deferring_interrupts():  # Ctrl-C (in any thread) after the last one only
        try:
            for entry in sorted(p.name for p in staging.iterdir()):
                os.rename(staging / entry, destination / entry)
                moved.append(entry)
            staging.rmdir()
        except OSError:
            for entry in moved:  # back into the staging folder, which the caller removes
                os.rename(destination / entry, staging / entry)
            raise


def _swap_in(staging: Path, destination: Path, replace: bool) -> None:
    """Move the complete ``staging`` folder to ``destination``, the old one out of the way
    only now."""
    if destination.is_dir() and not any(destination.iterdir()):
        destination.rmdir()
    if not (destination.exists() or destination.is_symlink()):
        os.rename(staging, destination)
        return
    if not replace:
        raise OSError(f"{destination}: appeared while writing; the new output was not written "
                      "(add --force to replace it)")
    old = Path(tempfile.mkdtemp(prefix=f".{destination.name}.old-", dir=destination.parent))
    aside = old / destination.name
    # Ctrl-C (in any thread) is held back until both renames are done and the old one is gone
    with deferring_interrupts():
        try:
            os.rename(destination, aside)
        except OSError:
            old.rmdir()
            raise
        try:
            os.rename(staging, destination)
        except OSError:
            os.rename(aside, destination)  # put the old one back
            old.rmdir()
            raise
        _remove(old)
