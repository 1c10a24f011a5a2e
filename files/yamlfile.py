"""Reading YAML files people type: one place that turns every way a file can be
unreadable (missing, a folder, not UTF-8 text, binary, not YAML, nested too
deep) into one :class:`~nearlight.errors.UserError` line naming the file."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from ..errors import UserError

#: Larger files are not scene or sweep files (and would only waste memory).
MAX_BYTES = 16 << 20


def read_text_file(path: str | os.PathLike, *, what: str) -> str:
    """The text of a UTF-8 file, or a :class:`UserError` naming it.

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be, for messages (e.g. ``"scene file"``).
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if path.is_dir():
            raise UserError(f"{path}: is a folder (expected a {what})")
        if size > MAX_BYTES:
            raise UserError(f"{path}: {size} bytes, too large for a {what} (at most {MAX_BYTES})")
        data = path.read_bytes()
    except OSError as exc:
        raise UserError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise UserError(
            f"{path}: line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x}); a {what} is UTF-8 text"
        ) from None
    text = text.removeprefix("\ufeff")  # a byte-order mark some editors write
    if "\x00" in text:
        line = text[: text.index("\x00")].count("\n") + 1
        raise UserError(f"{path}: line {line}: binary content (a NUL byte); a {what} is UTF-8 text")
    return text


def load_yaml_file(path: str | os.PathLike, *, what: str) -> Any:
    """Parse a UTF-8 YAML file (``yaml.safe_load``), or a :class:`UserError` naming it and the line."""
    text = read_text_file(path, what=what)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise UserError(f"{path}: not valid YAML{where}: {' '.join(str(problem).split())}") from None
    except RecursionError:
        raise UserError(f"{path}: not a {what}: nested too deeply") from None
