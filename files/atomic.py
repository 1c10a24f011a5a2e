"""Atomic writes: a file appears whole or not at all (the one implementation).

Used for every file nearlight writes in place of another: sweep results and
manifests, estimate JSON, figures, render cache entries. Capture folders are
written the same way, a folder at a time (:func:`nearlight.capture.write_capture`).
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: str | os.PathLike, write: Callable[[str], object], *, suffix: str = ".partial") -> None:
    """Call ``write(tmp)`` on a temporary sibling of ``path``, then rename it onto ``path``.

    The sibling is ``.<name>.<random><suffix>`` in the same folder (so the
    rename is atomic); it is removed when ``write`` or the rename fails, also
    on Ctrl-C and SIGTERM. Only a process killed with SIGKILL can leave one.

    Parameters
    ----------
    path : path-like
        The file to create or replace; its folder must exist.
    write : callable
        Writes the whole file at the path it is given (a ``str``).
    suffix : str, optional
        Ending of the temporary name (some writers choose the format by it).

    Raises
    ------
    OSError
        From creating, writing or renaming the file; the caller turns it into
        a :class:`~nearlight.errors.UserError` naming ``path`` where the user chose it.
    """
    from ..errors import disk_full, no_space

    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    except OSError as exc:
        raise (no_space(path) if disk_full(exc) else exc) from None
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if disk_full(exc):
            raise no_space(path) from None
        raise


def check_not_full(path: Path) -> None:
    """Raise ``OSError(ENOSPC)`` when the file system holding ``path`` has no free block left.

    OpenEXR's writer reports no failed write: on a full disk it leaves a
    truncated file and returns (tried on ``/dev/full``). So after writing one,
    a file system with no block free (``statvfs``'s ``f_bfree``, the root
    reserve included) counts as a full disk, and the write as failed.
    """
    try:
        full = os.statvfs(path.parent).f_bfree == 0
    except (OSError, AttributeError):  # no statvfs (Windows): nothing to add to the writer's own errors
        return
    if full:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def cannot_write(path: str | os.PathLike, exc: OSError, what: str = "there") -> Exception:
    """The one line for an ``OSError`` while writing ``path``: :func:`no_space` for a full disk, else
    ``"<path>: cannot write <what> (<reason>)"``."""
    from ..errors import UserError, disk_full, no_space

    if disk_full(exc):
        return no_space(path)
    return UserError(f"{path}: cannot write {what} ({exc.strerror or exc})")


def write_json(path: str | os.PathLike, doc: object, *, what: str = "there") -> Path:
    """Write ``doc`` as indented JSON at ``path``, atomically, creating its folder.

    Raises
    ------
    UserError
        ``path`` cannot be written: ``"<path>: cannot write <what> (<reason>)"``.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(doc, indent=2) + "\n"))
    except OSError as exc:
        raise cannot_write(path, exc, what) from None
    return path
