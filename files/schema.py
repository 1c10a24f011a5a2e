"""Validated documents: a pydantic model's first error as one line, the numbers, names and paths a document may hold.

The one home of the rule every validated file follows (scene, sweep, GSA files; suite manifests;
reproduction references): the first error of a :class:`pydantic.ValidationError` becomes one
:class:`~nearlight.errors.UserError` line ``<file>: <dotted key>: <what was expected>``.

Names and paths read from a document (a suite manifest's case ids, case folders and file names)
are the document's to choose only inside its own folder: :func:`check_name` and
:func:`check_relative` are the validators its model uses, and :func:`inside` checks the place on
disk (a symbolic link out of the folder is refused as a ``..`` is).

Numbers read from JSON or YAML by hand (capture files, rig files, sweep axes) are checked with
:func:`is_number` and :func:`all_numbers`: ``true`` is not 1, and numpy would turn ``"135"`` into a float.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path, PurePosixPath
from typing import Any, TypeVar

from ..errors import UserError

M = TypeVar("M")

#: A name that is one path component on every file system: letters, digits, ``.``, ``_``, ``-``; not
#: starting with a dot (no ``.``, ``..``, no hidden name).
NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")


def is_number(x: Any) -> bool:
    """Whether ``x`` is a finite int or float, not a bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def all_numbers(x: Any) -> bool:
    """Whether ``x`` is an int or float that is not a bool (NaN and infinities included), or nested lists of them."""
    if isinstance(x, list):
        return all(all_numbers(v) for v in x)
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def first_error(exc: Any) -> str:
    """``<dotted key>: <message>`` of a :class:`pydantic.ValidationError`'s first error (``<top>``: the whole document)."""
    err = exc.errors(include_url=False)[0]
    loc = ".".join(str(x) for x in err["loc"]) or "<top>"
    return f"{loc}: {err['msg'].removeprefix('Value error, ')}"


def validate(model: type[M], doc: Any, *, where: str, context: Any = None) -> M:
    """``model.model_validate(doc)``, its first error one :class:`UserError` line starting ``<where>: ``."""
    from pydantic import ValidationError

    try:
        return model.model_validate(doc, context=context)  # type: ignore[attr-defined]
    except ValidationError as exc:
        raise UserError(f"{where}: {first_error(exc)}") from None


def check_name(value: Any) -> str:
    """A pydantic validator: ``value`` is a :data:`NAME` (raises ``ValueError`` naming it otherwise)."""
    if not isinstance(value, str) or not NAME.fullmatch(value):
        raise ValueError(f"expected a plain name (letters, digits, '.', '_', '-'; no '/', no leading dot), got {value!r}")
    return value


def check_relative(value: Any) -> str:
    """A pydantic validator: ``value`` is a relative path that stays in its folder (``a/b``: no ``..``, not
    absolute, no empty or hidden component, no NUL or backslash)."""
    ok = isinstance(value, str) and value and "\x00" not in value and "\\" not in value
    parts = PurePosixPath(value).parts if ok else ()
    if not ok or value.startswith("/") or any(not NAME.fullmatch(p) for p in parts):
        raise ValueError(f"expected a relative path inside the folder (no '..', not absolute), got {value!r}")
    return value


def inside(folder: str | os.PathLike, relative: str, *, where: str) -> Path:
    """``folder / relative``, refused (:class:`UserError` starting ``<where>: ``) when it resolves outside
    ``folder`` (a symbolic link that leads out)."""
    folder = Path(folder)
    path = folder / relative
    try:
        path.resolve().relative_to(folder.resolve())
    except ValueError:
        raise UserError(f"{where}: {relative!r} leads outside {folder} (a link out of the folder); refused") from None
    return path
