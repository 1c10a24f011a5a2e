"""Atomic writes: a file or a folder appears whole or not at all (the one implementation of each).

:func:`atomic_write` (and on it :func:`write_text` and :func:`write_json`) is
used for every file nearlight writes: sweep results and manifests, reports,
estimate JSON, figures, render cache entries. :func:`write_folder` is used for
every folder written as one thing: captures (:func:`nearlight.capture.write_capture`)
and rig exports (:func:`nearlight.rig.export.export_rig`).
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from ..errors import UserError, disk_full, no_space
from .jsonable import json_text


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
    if disk_full(exc):
        return no_space(path)
    return UserError(f"{path}: cannot write {what} ({exc.strerror or exc})")


def write_text(path: str | os.PathLike, text: str, *, what: str = "there") -> Path:
    """Write ``text`` (UTF-8) at ``path``, atomically (:func:`atomic_write`), creating its folder.

    Raises
    ------
    UserError
        ``path`` cannot be written: ``"<path>: cannot write <what> (<reason>)"``
        (:func:`cannot_write`).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    except OSError as exc:
        raise cannot_write(path, exc, what) from None
    return path


def write_json(path: str | os.PathLike, doc: object, *, what: str = "there") -> Path:
    """Write ``doc`` as JSON indented by 2, with a final newline, at ``path``: :func:`write_text`."""
    return write_text(path, json_text(doc), what=what)


def write_folder(path: str | os.PathLike, fill: Callable[[Path], object], *,
                 existing: Callable[[Path], object]) -> Path:  # fmt: skip
    """Call ``fill(tmp)`` on a new temporary sibling folder of ``path``, then rename it onto ``path``.

    The sibling is ``.<name>.<random>.partial`` in the same folder (so the
    rename is atomic, and a folder that is not whole never has the name); it is
    removed when ``fill`` or the rename fails, also on Ctrl-C and SIGTERM. Only
    a process killed with SIGKILL can leave one.

    Parameters
    ----------
    path : path-like
        The folder to create (or replace); its parent is created.
    fill : callable
        Writes every file of the folder into the folder it is given.
    existing : callable
        Called with ``path`` when something is there once ``fill`` is done
        (checked again at that last moment): it raises (a
        :class:`~nearlight.errors.UserError`) when that may not be replaced.
        When it returns, the old folder is moved into a hidden sibling
        ``.<name>.<random>.old`` first and removed only once the new one is in
        place, so a failure keeps one of the two whole.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    UserError
        ``path`` cannot be written (:func:`cannot_write`), or ``existing``'s.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    except OSError as exc:
        raise cannot_write(path, exc) from None
    old = None

    def restore() -> None:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and not path.exists() and (old / path.name).exists():
            (old / path.name).rename(path)

    try:
        fill(tmp)
        if path.exists() or path.is_symlink():
            existing(path)
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            path.rename(old / path.name)
        tmp.rename(path)
    except OSError as exc:
        restore()
        raise cannot_write(path, exc) from None
    except BaseException:
        restore()
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return path
