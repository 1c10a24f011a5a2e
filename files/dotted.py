"""Dotted keys into nested mappings: ``"lamp.position"`` -> ``doc["lamp"]["position"]``.

The one implementation behind scene ``--set`` overrides and sweep axes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..errors import UserError


def set_dotted(doc: dict[str, Any], key: str, value: Any, *, where: str) -> None:
    """Set ``doc["a"]["b"] = value`` for ``key = "a.b"``, creating sections on the way.

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
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise UserError(f"{where}: {'.'.join(parts[: i + 1])}: is not a section, cannot set {key}")
        node = child
    node[parts[-1]] = value


def get_dotted(doc: Mapping[str, Any], key: str, default: Any = None) -> Any:
    """``doc["a"]["b"]`` for ``key = "a.b"``, or ``default`` when absent."""
    node: Any = doc
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return default
        node = node[part]
    return node
