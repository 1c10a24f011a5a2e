"""What a kept number depends on, as one hash: the code that computes it, its input files, its packages.

A run kept from another machine (``reports/references/``) is evidence about
today's code only while the code behind it is unchanged. :func:`fingerprint`
hashes what a reproduction table or a scorecard depends on: the estimator,
the generator, the scoring and the first-stage study's analytic code
(:data:`ENTRIES`: their static import closures, hashed as code tokens like
``provenance.json``, :func:`nearlight.evaluation.engine.provenance.code_hash`),
the input files (sweep, scene or suite file, as bytes) and the versions of the
packages that compute the numbers (:data:`PACKAGES`). Left out: the two
modules that choose the renderer's variant and LLVM target (:data:`NOT_CODE`):
what they chose is recorded in the environment, and is exactly what the
tolerance classes judge. The estimator package's ``__init__`` imports every
method, so a change to any method changes every fingerprint; a narrower
closure would keep references longer.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from ...files.digests import file_sha256
from .environment import PACKAGE_ROOT
from .provenance import _rel, code_hash, dependencies

#: Where runs kept from other machines live.
REFERENCES = PACKAGE_ROOT / "reports" / "references"
#: Modules whose import closure a kept number depends on.
ENTRIES = ("nearlight.estimator", "nearlight.generator", "nearlight.evaluation.scoring.metrics",
           "nearlight.evaluation.scoring.matching", "nearlight.evaluation.paper.fidelity")
#: Files of that closure that choose the renderer, not a number: their choice is in the environment.
NOT_CODE = ("generator/llvm.py", "generator/jit_target.py")
#: Packages whose version changes a kept number.
PACKAGES = ("mitsuba", "drjit", "numpy", "scipy")


def fingerprints(inputs: Mapping[str, Iterable[Path]]) -> dict[str, str]:
    """``{name: SHA-256 (hex)}`` of what numbers made from each name's ``inputs`` (sweep, scene or suite
    files) depend on, today: the code and packages are hashed once for all of them (0.6 s)."""
    packages = {}
    for name in PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            packages[name] = None
    code = {_rel(p): code_hash(p) for p in dependencies(ENTRIES) if _rel(p) not in NOT_CODE}
    out = {}
    for name, files in inputs.items():
        doc = {"code": code, "inputs": {_rel(p): file_sha256(Path(p)) for p in files}, "packages": packages}
        out[name] = hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
    return out


def fingerprint(inputs: Iterable[Path]) -> str:
    """SHA-256 (hex) of what numbers made from ``inputs`` (sweep, scene or suite files) depend on, today."""
    return fingerprints({"": inputs})[""]
