"""Reading YAML people type: one place that turns every way a file can be
unreadable (missing, a folder, not UTF-8 text, binary, not YAML, nested too
deep) into one :class:`~nearlight.errors.UserError` line naming the file, and
the one reader of ``--set KEY=VALUE`` (:func:`parse_setting`).

Files and ``--set`` values are read alike, as YAML with one change from
PyYAML's YAML 1.1: a number in exponent form without a dot (``1e-6``) is a
number, as in YAML 1.2 and JSON, not the string ``"1e-6"``."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import yaml

from ..errors import UserError, one_line

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
        with open(path, "rb") as f:  # at most MAX_BYTES + 1: a device (/dev/zero) or a pipe states no size
            data = f.read(MAX_BYTES + 1)
        if len(data) > MAX_BYTES:
            raise UserError(f"{path}: more than {MAX_BYTES} bytes, too large for a {what} (a device or a stream?)")
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


class _Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` reading ``1e-6`` as a float (YAML 1.2), as people mean it."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def load_yaml(text: str) -> Any:
    """Parse YAML text as nearlight reads every file and ``--set`` value (``yaml.safe_load``, plus ``1e-6``)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader


def parse_setting(item: str, *, example: str) -> tuple[str, Any]:
    """``"KEY=VALUE"`` of a ``--set`` option to ``(KEY, VALUE)``, VALUE read as YAML.

    Parameters
    ----------
    item : str
        The option's argument, e.g. ``"lamp.position=[0.2, 0.1, 0.3]"``.
    example : str
        A valid setting, for the message when ``item`` is not one.

    Raises
    ------
    UserError
        ``--set 'ITEM': ...`` for a missing ``=`` or key, or a value that is not YAML.
    """
    key, sep, text = str(item).partition("=")
    if not sep or not key.strip():
        raise UserError(f"--set {item!r}: expected KEY=VALUE, e.g. {example}")
    try:
        return key.strip(), load_yaml(text)
    except (yaml.YAMLError, RecursionError):
        raise UserError(f"--set {item!r}: value is not valid YAML") from None


def load_yaml_file(path: str | os.PathLike, *, what: str) -> Any:
    """Parse a UTF-8 YAML file (:func:`load_yaml`), or a :class:`UserError` naming it and the line."""
    text = read_text_file(path, what=what)
    try:
        return load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise UserError(f"{path}: not valid YAML{where}: {one_line(problem)}") from None
    except RecursionError:
        raise UserError(f"{path}: not a {what}: nested too deeply") from None


def load_yaml_mapping(path: str | os.PathLike, *, what: str, keys: str) -> dict:
    """A YAML file that must hold a mapping (a sweep, GSA or suite file), or a one-line :class:`UserError`.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for messages (e.g. ``"sweep file"``).
    keys : str
        Its top-level keys, for the message when it is not a mapping (e.g.
        ``"name, scene, axes, seeds, methods"``).
    """
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such {what}")
    doc = load_yaml_file(p, what=what)
    if not isinstance(doc, dict):
        raise UserError(f"{p}: expected a mapping of {what.removesuffix(' file')} keys ({keys})")
    return doc
