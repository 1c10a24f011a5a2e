"""Plain-JSON views of nested results (numpy arrays and scalars, paths, NaN), and the JSON text nearlight writes."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

import numpy as np


def jsonable(x: Any) -> Any:
    """``x`` with every numpy array, numpy scalar and path made plain JSON.

    Mappings and sequences are converted recursively; NaN and ±Inf become
    ``None`` (JSON has no NaN: a missing number must read as missing, not as a
    parse error in another tool).
    """
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, PurePath):
        return str(x)
    return x


def json_text(doc: Any) -> str:
    """``doc`` as the JSON text of every file nearlight writes: indented by 2, ASCII, a final newline."""
    return json.dumps(doc, indent=2) + "\n"
