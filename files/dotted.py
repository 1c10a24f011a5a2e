"""Dotted keys into nested mappings: ``"lamp.position"`` -> ``doc["lamp"]["position"]``.

The one implementation behind scene ``--set`` overrides and sweep axes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..errors import UserError


def set_dotted(doc: dict[str, Any], key: str, value: Any, *, where: str) -> None:
    """Set ``doc["a"]["b"] = value`` for ``key = "a.b"``, creating sections on the way.

    A list of sections on the way is indexed by a number from 0: ``lamps.1.position`` is
    ``doc["lamps"][1]["position"]`` (a list of numbers is a value, not a section, but its last
    part may index one of its numbers: ``nuisances.calibration.position_m.0``, a study's input).

    Raises
    ------
    UserError
        A section on the way holds a value, not a mapping; the message starts
        with ``where`` (the file or option being applied).
    """
    node = doc
    parts = str(key).split(".")
    if not all(p.strip() for p in parts):
        raise UserError(f"{where}: {key!r}: expected a dotted key of names, e.g. lamp.position")
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            child = node[_index(node, part, parts[:i], where)]
        else:
            child = node.setdefault(part, {})
        last_number = i == len(parts) - 2 and isinstance(child, list) and parts[-1].isdigit()
        if not (isinstance(child, dict) or _sections(child) or last_number):
            raise UserError(f"{where}: {'.'.join(parts[: i + 1])}: is not a section, cannot set {key}")
        node = child
    if isinstance(node, list):
        node[_index(node, parts[-1], parts[:-1], where)] = value
    else:
        node[parts[-1]] = value


def _sections(x: Any) -> bool:
    """Whether ``x`` is a list of sections (mappings), which a dotted key indexes (a list of numbers is a value)."""
    return isinstance(x, list) and bool(x) and all(isinstance(item, dict) for item in x)


def _index(items: list, part: str, before: list[str], where: str) -> int:
    """``part`` as an index of the list ``items`` (at dotted key ``before``), or a one-line :class:`UserError`."""
    if not (part.isdigit() and int(part) < len(items)):
        name = ".".join(before)
        raise UserError(
            f"{where}: {name}.{part}: {name} is a list of {len(items)}: expected an index from 0 to {len(items) - 1}"
        )
    return int(part)


def get_dotted(doc: Mapping[str, Any], key: str, default: Any = None) -> Any:
    """``doc["a"]["b"]`` for ``key = "a.b"`` (a list indexed by a number), or ``default`` when absent."""
    node: Any = doc
    for part in key.split("."):
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
            continue
        if not isinstance(node, Mapping) or part not in node:
            return default
        node = node[part]
    return node
