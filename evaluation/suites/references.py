"""Suite builds and scorecards kept from other CPUs, for as long as the code behind them is unchanged.

A built suite is not shipped: every user renders it on their own CPU. Whether
their build and their scores agree with ours is checked against a kept one:
``reports/references/scores/<suite>/<name>/`` holds another machine's
``manifest.json`` (its per-layer digests, :func:`nearlight.evaluation.suites.suite.verify_against`)
and, per method, the rows of its scorecard (``<method>/``: ``results.parquet``,
``sweep.json``, ``environment.json``, ``scorecard.json``: what ``nearlight
compare`` reads), with ``reference.json``: the build's CPU, flags and LLVM
target, and the :func:`nearlight.evaluation.engine.fingerprint.fingerprint` of
the suite file and the code. The reference applies while that fingerprint is
today's. ``tests/evaluation/suites/test_cross_cpu_scores.py`` builds
``suites/crosscheck-v1.yaml`` on the machine that runs the tests and compares
its build and scores with every applicable reference.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ...errors import UserError
from ...files.atomic import write_json
from ..engine.fingerprint import REFERENCES, fingerprint
from .suite import MANIFEST, read_manifest_file

#: Where suite references are kept (one folder per suite, one per reference in it).
FOLDER = REFERENCES / "scores"
#: The record of a reference.
RECORD = "reference.json"
#: The files of a score folder that ``nearlight compare`` reads.
SCORE_FILES = ("results.parquet", "sweep.json", "environment.json", "scorecard.json")


def keep(build: Path, scores: Iterable[Path], suite_file: Path, name: str, *, note: str,
         folder: Path = FOLDER) -> Path:
    """Keep a suite build's manifest and its scorecards (``scores``: ``nearlight score --out`` folders).

    Raises
    ------
    UserError
        A folder is not a build or a score folder of that suite, or ``name`` is taken.
    """
    manifest = read_manifest_file(Path(build) / MANIFEST)
    target = folder / manifest["suite"] / name
    if target.exists():
        raise UserError(f"{target}: a reference of that name exists (references are kept, not replaced)")
    methods = {}
    for score in map(Path, scores):
        try:
            card = json.loads((score / "scorecard.json").read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise UserError(f"{score}: not a score folder ({exc})") from None
        if card.get("cases_hash") != manifest["cases_hash"]:
            raise UserError(f"{score}: a scorecard of {card.get('suite')!r}, not of the build {build}")
        methods[card["method"]] = score
    for method, score in methods.items():
        (target / method).mkdir(parents=True)
        for file in SCORE_FILES:
            shutil.copyfile(score / file, target / method / file)
    shutil.copyfile(Path(build) / MANIFEST, target / MANIFEST)
    env = manifest.get("environment") or {}
    return write_json(target / RECORD, {
        "suite": manifest["suite"], "cases_hash": manifest["cases_hash"], "made_by": manifest.get("generator_version"),
        "cpu": env.get("cpu"), "cpu_flags": env.get("cpu_flags"), "jit_target": env.get("jit_target", "host"),
        "methods": sorted(methods), "fingerprint": fingerprint([suite_file]), "note": note,
    }, what="the reference record")


def references(suite_file: Path, suite: str, folder: Path = FOLDER) -> list[tuple[str, Path, dict[str, Any], bool]]:
    """Every kept reference of ``suite``: ``(name, folder, record, applicable)``.

    ``applicable`` is False when the code or the suite file changed since it was kept.
    """
    now = fingerprint([suite_file])
    out = []
    for record_path in sorted((folder / suite).glob(f"*/{RECORD}")):
        record = json.loads(record_path.read_text(encoding="utf-8"))
        out.append((record_path.parent.name, record_path.parent, record, record["fingerprint"] == now))
    return out
