"""``nearlight suite export``: a built suite's inputs without its truth, for a method run elsewhere.

An export is a folder::

    INPUTS/manifest.json               format nearlight-suite-inputs/1: suite, version, cases_hash,
                                       per case its id, path and the sha256 of its files
    INPUTS/cases/NNN/input/capture.*   what the method sees (the built suite's input captures)

Only what a method may see goes out: the input captures (no ``truth`` key, no
``truth_*`` channel, no generator record: :func:`~nearlight.evaluation.suites.suite.strip_truth`,
which the build applied and the export checks again), each case's id and path.
The cases' categories (the lamp's distance, the material...), seeds and the truth
captures stay behind. The export keeps the answers out of the folder, not out of
reach: a suite file is public and its renders deterministic, so anyone can rebuild
the truth; it guards against a method that reads what it is handed whole, not against
a participant who wants to cheat (a blind test needs a suite file kept private).

``nearlight score INPUTS --check FILE`` checks a results file against an export as
against the built suite; scoring needs the built suite (the truth).
"""

from __future__ import annotations

import functools
import json
import shutil
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StrictInt, field_validator

from ... import __version__
from ...capture import read_capture
from ...errors import UserError, one_line
from ...files.atomic import write_folder, write_json
from ...files.jsonable import jsonable
from ...files.outputs import check_folder
from ...files.schema import check_name, check_relative, inside, validate
from .suite import INPUT, MANIFEST, checksum_problems, read_manifest, strip_truth, suite_cases, unique_cases

#: An export's manifest ``format``.
FORMAT = "nearlight-suite-inputs/1"


def export_inputs(suite_dir: str | Path, out: str | Path) -> tuple[Path, int]:
    """Write the truth-free inputs of the built suite ``suite_dir`` into ``out`` (a new folder).

    Parameters
    ----------
    suite_dir : path-like
        A built suite; its checksums are verified first.
    out : path-like
        The export folder: must not exist (or be empty); written whole or not at all.

    Returns
    -------
    manifest : Path
    n : int
        Cases exported.
    """
    suite_dir = Path(suite_dir)
    manifest = read_manifest(suite_dir)
    out = check_folder(out, what="export folder")
    if out.is_dir() and any(out.iterdir()):
        raise UserError(f"{out}: not empty; an export is written into a new folder (choose another --out)")
    problems = checksum_problems(suite_dir, manifest)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(problems[0] + more + "; rebuild or re-download the suite before exporting it")
    cases = []
    for c in manifest["cases"]:
        files = {rel: sha for rel, sha in c["files"].items() if rel.split("/")[0] == INPUT}
        seen = read_capture(suite_dir / c["path"] / INPUT)
        if leaked(seen):
            raise UserError(f"{suite_dir / c['path'] / INPUT}: holds truth ({', '.join(leaked(seen))}); rebuild the "
                            "suite with this nearlight")  # fmt: skip
        cases.append({"id": c["id"], "path": c["path"], "files": files})
    doc = {"format": FORMAT, "suite": manifest["suite"], "version": manifest["version"],
           "description": manifest.get("description", ""), "cases_hash": manifest["cases_hash"],
           "nearlight_version": __version__, "cases": cases}  # fmt: skip

    def fill(tmp: Path) -> None:
        for c in cases:
            for rel in c["files"]:
                dest = tmp / c["path"] / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(suite_dir / c["path"] / rel, dest)
        write_json(tmp / MANIFEST, jsonable(doc))
        bad = checksum_problems(tmp, doc)
        if bad:
            raise UserError(f"{out}: the copy does not match the suite's checksums ({bad[0]})")

    write_folder(out, fill, existing=_empty_only)
    return out / MANIFEST, len(cases)


def _empty_only(out: Path) -> None:
    """``write_folder``'s last check: only an empty folder (checked before the copy) is replaced."""
    if not out.is_dir() or any(out.iterdir()):
        raise UserError(f"{out}: appeared while exporting and is not an empty folder; nothing was replaced")


def leaked(capture: Any) -> list[str]:
    """What of the truth ``capture`` holds (empty: none): its ``truth``, ``truth_*`` layers, truth meta keys."""
    stripped = strip_truth(capture)
    found = ["truth"] if capture.truth is not None else []
    found += sorted(set(capture.extra) - set(stripped.extra)) + sorted(set(capture.meta) - set(stripped.meta))
    return found


def read_inputs(folder: str | Path) -> tuple[dict[str, Any], list[tuple[str, Path]]]:
    """The suite and cases of a built suite or of an export, for checking a results file.

    Returns
    -------
    suite : dict
        The manifest (``suite``, ``version``, ``cases_hash``, ``cases``...).
    cases : list of (case id, input capture folder)
    """
    folder = Path(folder)
    path = folder / MANIFEST
    try:
        doc = json.loads(path.read_bytes().decode("utf-8")) if path.is_file() else None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise UserError(f"{path}: not a readable suite manifest ({one_line(exc)[:120]})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        manifest = read_manifest(folder)  # a built suite (its own one-line errors)
        return manifest, suite_cases(folder, manifest)
    validate(_model(), doc, where=str(path))
    for c in doc["cases"]:
        inside(folder, c["path"], where=f"{path}: cases.{c['id']}.path")
    return doc, suite_cases(folder, doc)


@functools.cache
def _model() -> type:
    Name = Annotated[str, AfterValidator(check_name)]
    Relative = Annotated[str, AfterValidator(check_relative)]
    Sha256 = Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]

    class Case(BaseModel):
        model_config = ConfigDict(extra="forbid")
        id: Name
        path: Relative
        files: dict[Relative, Sha256] = Field(min_length=1)

    class Inputs(BaseModel):
        model_config = ConfigDict(extra="allow")
        format: Literal["nearlight-suite-inputs/1"]
        suite: str = Field(min_length=1)
        version: StrictInt = Field(ge=1)
        cases_hash: str = Field(min_length=1)
        cases: list[Case] = Field(min_length=1)
        _unique = field_validator("cases")(unique_cases)

    return Inputs

