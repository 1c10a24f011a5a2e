"""Output places: what nearlight may create, and what it may replace.

The rule (README, "Output places"): nearlight never deletes or replaces a file
or folder it did not write. Every verb checks its output places *before* it
does any work, so a refused output costs nothing and leaves the place
untouched:

- a **capture folder** (``render --out``) is replaced only with
  ``--overwrite`` and only when it is a capture: see :func:`is_capture_dir`;
- a **file** (``show --out``, ``estimate --json`` / ``--plot``, the files of
  ``report`` and ``reproduce``) is replaced only when it is a regular file of
  the kind the verb writes (:data:`KINDS`: a PNG image for a figure, an
  estimate JSON for ``--json``, ...); anything else there is refused;
- a **folder** that outputs go into (``report --out``, ``reproduce --out``,
  ``--cache``) must be a folder or creatable; files in it that the verb does
  not write are left alone.

Every check raises :class:`~nearlight.errors.UserError` with one line naming
the place and what was expected.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..errors import UserError

#: The capture format's file names (see :mod:`nearlight.capture`).
CAPTURE_FILES = ("capture.json", "capture.exr")
#: ``capture.json``'s format prefix.
CAPTURE_FORMAT_PREFIX = "nearlight-capture/"
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def is_capture_dir(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder nearlight wrote as a capture.

    A capture folder holds exactly ``capture.json`` and ``capture.exr`` (both
    regular files, nothing else: no sub-folder, no hidden file), its
    ``capture.json`` is a JSON object whose ``format`` starts with
    ``nearlight-capture/``, and its ``capture.exr`` starts with the OpenEXR
    magic number. Only such a folder may be replaced by ``--overwrite``.

    An interrupted write (``SIGKILL``) can leave a hidden sibling
    ``.<name>.<random>.partial``; it is outside the folder, never taken for a
    capture, and never removed by nearlight.
    """
    path = Path(path)
    if path.is_symlink() or not path.is_dir():
        return False
    try:
        names = sorted(os.listdir(path))
    except OSError:
        return False
    if names != sorted(CAPTURE_FILES):
        return False
    if any((path / n).is_symlink() or not (path / n).is_file() for n in names):
        return False
    doc = _read_json(path / "capture.json")
    fmt = doc.get("format") if isinstance(doc, dict) else None
    return isinstance(fmt, str) and fmt.startswith(CAPTURE_FORMAT_PREFIX) and _starts_with(path / "capture.exr", _EXR_MAGIC)


def check_capture_out(out: str | os.PathLike, *, overwrite: bool, flag: str = "--overwrite") -> Path:
    """Raise :class:`UserError` unless a capture can be written at ``out``.

    ``out`` must not exist, or (with ``overwrite``) be a capture folder
    (:func:`is_capture_dir`); its parent must be a writable folder or creatable.
    Nothing is created or removed.
    """
    out = Path(out)
    if out.exists() or out.is_symlink():
        if not overwrite:
            raise UserError(f"{out}: already exists (choose another --out, or pass {flag} to replace a capture)")
        if not is_capture_dir(out):
            raise UserError(
                f"{out}: {flag} replaces only a capture (a folder holding exactly {' and '.join(CAPTURE_FILES)}); "
                f"this is not one, so it was left untouched"
            )
    _check_parent(out)
    return out


def _check_parent(out: Path) -> None:
    """The nearest existing ancestor of ``out`` must be a writable folder."""
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        if parent.is_symlink():  # a dangling link: mkdir would fail
            break
        parent = parent.parent
    if not parent.is_dir():
        raise UserError(f"{out}: cannot write there ({parent} is not a folder)")
    if not os.access(parent, os.W_OK | os.X_OK) or not _can_create_in(parent):
        raise UserError(f"{out}: cannot write there ({parent} is not a writable folder)")


def _can_create_in(folder: Path) -> bool:
    """Whether a folder can really be made in ``folder``: made and removed at once (``os.access`` says yes to root
    in ``/proc`` and ``/sys``, where ``mkdir`` then fails)."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".nearlight-probe-", dir=folder))
    except OSError:
        return False
    return True


def check_folder(folder: str | os.PathLike, *, what: str = "output folder") -> Path:
    """Raise :class:`UserError` unless ``folder`` is a writable folder or can be created (nothing is created)."""
    folder = Path(folder)
    if folder.exists():
        if not folder.is_dir():
            raise UserError(f"{folder}: exists and is not a folder (expected a {what})")
        if not os.access(folder, os.W_OK | os.X_OK) or not _can_create_in(folder):
            raise UserError(f"{folder}: cannot write there (not a writable folder)")
        return folder
    _check_parent(folder)
    return folder


def make_folder(folder: str | os.PathLike, *, what: str = "output folder") -> Path:
    """:func:`check_folder`, then create it (and its parents)."""
    folder = check_folder(folder, what=what)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{folder}: cannot create the {what} ({exc.strerror or exc})") from None
    return folder


# --------------------------------------------------------------------------- file kinds


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(magic)) == magic
    except OSError:
        return False


def _read_json(path: Path) -> object:
    try:
        if path.stat().st_size > 64 << 20:
            return None
        return json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, ValueError):
        return None


def _json_with(*keys: str) -> Callable[[Path], bool]:
    def check(path: Path) -> bool:
        doc = _read_json(path)
        return isinstance(doc, dict) and all(k in doc for k in keys)

    return check


def _has_format(doc: Any, prefix: str) -> bool:
    """Whether ``doc`` is a JSON object whose ``format`` starts with ``prefix``."""
    return isinstance(doc, dict) and isinstance(doc.get("format"), str) and doc["format"].startswith(prefix)


def _json_format(path: Path, prefix: str) -> bool:
    return _has_format(_read_json(path), prefix)


def _first_line_format(path: Path, prefix: str) -> bool:
    """Whether the first line of ``path`` is a JSON object whose ``format`` starts with ``prefix`` (JSON Lines)."""
    try:
        with open(path, "rb") as f:
            doc = json.loads(f.readline(1 << 16).decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return False
    return _has_format(doc, prefix)


def _text_starting(*prefixes: str) -> Callable[[Path], bool]:
    def check(path: Path) -> bool:
        try:
            with open(path, "rb") as f:
                head = f.read(4096).decode("utf-8", errors="strict").splitlines()
        except (OSError, UnicodeDecodeError):
            return False
        first = head[0] if head else ""
        return any(first.startswith(p) for p in prefixes)

    return check


#: What each kind of output file is (how nearlight recognises a file of that
#: kind before replacing it), and the suffix it must have.
KINDS: dict[str, tuple[str, str, Callable[[Path], bool]]] = {
    "png": (".png", "a PNG image", lambda p: _starts_with(p, _PNG_MAGIC)),
    "estimate": (".json", "an estimate written by `nearlight estimate --json`", _json_with("method", "lamp_position")),
    "reproduction-json": (".json", "a paper reproduction written by `nearlight reproduce`",
                          _json_with("nearlight_version", "experiments")),
    "reproduction-md": (".md", "a paper reproduction written by `nearlight reproduce`",
                        _text_starting("# Paper reproduction")),
    "scorecard-json": (".json", "a scorecard written by `nearlight score`", lambda p: _json_format(p, "nearlight-scorecard/")),
    "scorecard-md": (".md", "a scorecard written by `nearlight score`", _text_starting("# Scorecard")),
    "results": (".jsonl", "a results file written by `nearlight score`",
                lambda p: _first_line_format(p, "nearlight-results/")),
    "comparison": (".json", "a comparison written by `nearlight compare --json`", _json_with("baseline", "checks")),
    "provenance": (".json", "a provenance record written by nearlight", _json_with("parts")),
    "report-md": (".md", "a sweep report written by `nearlight report`", _text_starting("# Sweep report")),
    # Report tables: a header naming a method column, or pandas' empty table.
    "report-csv": (".csv", "a report table written by `nearlight report`", lambda p: _csv_header_ok(p)),
}  # fmt: skip


def _csv_header_ok(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            first = f.read(4096).decode("utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return False
    head = first[0] if first else ""
    return head in ("", '""') or "method" in head.split(",")


def check_file_out(path: str | os.PathLike, kind: str, *, flag: str | None = None) -> Path:
    """Raise :class:`UserError` unless ``path`` may be written as a file of ``kind``.

    The name must end in the kind's suffix; an existing ``path`` must be a
    regular file of that kind (:data:`KINDS`), which is then replaced; its
    folder must be writable or creatable. Nothing is written.

    Parameters
    ----------
    path : path-like
    kind : str
        A key of :data:`KINDS`.
    flag : str, optional
        The option that named ``path`` (e.g. ``"--plot"``), for messages.
    """
    suffix, what, recognise = KINDS[kind]
    path = Path(path)
    named = f"{flag} {path}" if flag else str(path)
    if path.suffix.lower() != suffix:
        raise UserError(f"{named}: expected a file name ending in {suffix} (nearlight writes {what.split(' written')[0]} there)")
    if path.is_dir():
        raise UserError(f"{named}: is a folder (expected a {suffix} file name)")
    if path.exists() or path.is_symlink():
        if path.is_symlink() or not path.is_file() or not recognise(path):
            raise UserError(
                f"{named}: exists and is not {what}; nearlight replaces only files of that kind "
                f"(choose another name or remove it)"
            )
    _check_parent(path)
    return path


def check_files_in(folder: Path, files: dict[str, str]) -> None:
    """:func:`check_file_out` for every ``{name relative to folder: kind}`` (after :func:`check_folder`)."""
    check_folder(folder)
    for name, kind in files.items():
        check_file_out(folder / name, kind)
