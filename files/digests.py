"""Content digests: a stable hash of a JSON-ready value, and the sha256 of a file (one implementation each).

:func:`stable_hash` names what a value is, the same on every machine and every
run: task ids, sweep and suite hashes, case ids, analytic render keys.
:func:`file_sha256` is what a file holds: suite manifests' checksums,
provenance records' inputs, a mesh in a render key.
"""

from __future__ import annotations

import hashlib
import json
import os
from typing import Any


def stable_hash(obj: Any) -> str:
    """The first 16 hex digits of the sha256 of ``obj`` as JSON with sorted keys (``default=str`` for anything
    JSON cannot hold): equal values hash equally on every machine."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def file_sha256(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes, read in blocks of 1 MiB."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
