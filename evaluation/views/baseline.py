"""Regenerate a regression baseline, with the new run's verdict against the old one in writing.

A baseline (``reports/smoke-baseline``) is what ``nearlight compare`` holds new
code to, so replacing it is where a regression could slip in unseen. The one
way to regenerate it, :func:`regenerate_baseline` (``nearlight baseline``):

1. runs the sweep into a new folder beside the baseline, and reports it
   (:func:`~nearlight.evaluation.views.report.write_report`);
2. compares that run with the old baseline
   (:func:`~nearlight.evaluation.views.compare.compare_dirs`, the check the
   tests run);
3. refuses, leaving the old baseline as it was, when a check is ``worse`` or
   ``missing`` and no reason was given; with a reason (one line, the person's
   own words) it accepts them in writing;
4. writes the verdict beside the new rows: ``verdict.md`` (every ``worse``,
   ``missing`` and ``better`` line, the summary, the reason) and
   ``verdict.json`` (the same, read by the tests), records its provenance
   (part ``verdict``: the code of this module, of the comparison and of the
   run), drops the renders and result parts (not committed), carries over
   every file of the old folder that nearlight does not write (its README,
   the user's notes: :data:`WRITTEN`), and replaces the old folder in one
   rename (:func:`~nearlight.files.atomic.write_folder`).

So the tests can demand, for the code in the checkout, both a fresh baseline
(``tests/test_reports_fresh.py``: its provenance hashes) and a verdict record
made with it (``tests/evaluation/views/test_smoke_baseline.py``): a regression
enters the baseline only with a reason next to it.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import shutil
from pathlib import Path
from typing import Any

from ...errors import UserError
from ...files.atomic import write_folder, write_json, write_text
from ..engine.environment import code_version
from ..engine.provenance import FILE as PROVENANCE, record
from ..engine.run import run_sweep
from ..engine.store import RESULTS, SWEEP_JSON, read_sweep_json
from ..engine.sweep import load_sweep
from .compare import Check, check_thresholds, compare_dirs, verdict_counts
from .report import write_report

#: The verdict files written beside a baseline's rows.
VERDICT_JSON = "verdict.json"
VERDICT_MD = "verdict.md"
#: Format tag of ``verdict.json``.
VERDICT_FORMAT = "nearlight-baseline-verdict/1"
#: Folders of a run that a baseline does not keep (re-made by any run; ``.gitignore`` has them too).
NOT_KEPT = ("renders", "parts")
#: What a regeneration writes at the top of a baseline folder; anything else there (a README, notes) is
#: the user's or the project's, and is carried over into the new folder as it was.
WRITTEN = frozenset({"sweep.json", "results.parquet", "environment.json", PROVENANCE, "report", *NOT_KEPT,
                     VERDICT_JSON, VERDICT_MD})  # fmt: skip


@dataclasses.dataclass
class Regenerated:
    """What :func:`regenerate_baseline` did.

    Attributes
    ----------
    replaced : bool
        Whether the new run is now the baseline (False: refused, the old one kept).
    checks : list of Check
        The new run against the old baseline (empty for a first baseline).
    lines : list of str
        The comparison's printed lines (``compare_dirs``), or one line for a first baseline.
    """

    replaced: bool
    checks: list[Check]
    lines: list[str]

    @property
    def regressions(self) -> list[Check]:
        """The checks that are ``worse`` or ``missing``."""
        return [c for c in self.checks if c.regression]


class _Refused(Exception):
    """Raised inside the folder writer to discard the new run (a regression without a reason)."""


def check_baseline_folder(folder: str | Path) -> None:
    """Raise unless ``folder`` holds a sweep's results that nearlight wrote (``sweep.json`` and ``results.parquet``).

    A baseline is replaced whole, so the folder must be one nearlight made: a
    folder of the user's own files is never deleted.

    Raises
    ------
    UserError
        Naming the folder and what is missing.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder; a baseline is a sweep's results folder (nothing was replaced)")
    missing = [name for name in (SWEEP_JSON, RESULTS) if not (folder / name).is_file()]
    if missing:
        raise UserError(f"{folder}: not a sweep's results folder (no {' or '.join(missing)}); "
                        "`nearlight baseline` replaces only a baseline it made: choose another --out")
    read_sweep_json(folder)  # a damaged sweep.json is one line naming it


def regenerate_baseline(
    sweep_path: str | Path,
    out: str | Path,
    *,
    reason: str | None = None,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    tolerance: float = 0.05,
    alpha: float = 0.05,
    command: str | None = None,
) -> Regenerated:
    """Run ``sweep_path`` and make it the baseline ``out``, unless it is worse than the old one without a reason.

    Parameters
    ----------
    sweep_path : path-like
        The sweep file (``sweeps/smoke.yaml``).
    out : path-like
        The baseline folder; created when absent, else it must hold a sweep's
        results (:func:`check_baseline_folder`).
    reason : str, optional
        Why the new run may be worse than the old baseline (one line); required
        when a check is ``worse`` or ``missing``, recorded either way.
    workers, scheduler : optional
        As :func:`~nearlight.evaluation.engine.run.run_sweep`.
    progress : bool
        Progress bars on stderr.
    tolerance, alpha : float
        As :func:`~nearlight.evaluation.views.compare.compare_frames`.
    command : str, optional
        The command recorded in the provenance (default ``nearlight baseline SWEEP --out OUT``).

    Returns
    -------
    Regenerated

    Raises
    ------
    UserError
        A bad sweep file, an ``out`` that is not a baseline, a reason that is
        empty or more than one line, or a run that did not complete.
    """
    out = Path(out)
    if reason is not None:
        reason = reason.strip()
        if not reason or "\n" in reason:
            raise UserError("--reason: expected one line saying why the new baseline may be worse than the old")
    check_thresholds(tolerance, alpha)
    if out.exists():
        check_baseline_folder(out)
    sweep = load_sweep(sweep_path)
    command = command or f"nearlight baseline {sweep.source} --out {out}"
    result = Regenerated(False, [], [])

    def fill(tmp: Path) -> None:
        s = run_sweep(sweep, tmp, workers=workers, scheduler=scheduler, progress=progress, command=command)
        if not s.complete:
            raise UserError(f"{sweep.source}: the run did not complete ({s.ran} of {len(sweep.tasks)} tasks ran); "
                            f"nothing was replaced")
        write_report(tmp, command=command)
        if out.exists():
            result.checks, lines = compare_dirs(tmp, out, tolerance=tolerance, alpha=alpha)
            result.lines = [line.replace(str(tmp), "the new run") for line in lines]
        else:
            result.lines = [f"first baseline: {out} did not exist, nothing to compare"]
        if result.regressions and reason is None:
            raise _Refused
        for name in NOT_KEPT:
            shutil.rmtree(tmp / name, ignore_errors=True)
        for kept in sorted(set(_entries(out)) - WRITTEN):
            src = out / kept
            if src.is_dir() and not src.is_symlink():
                shutil.copytree(src, tmp / kept, symlinks=True)
            else:
                shutil.copy2(src, tmp / kept, follow_symlinks=False)
            result.lines.insert(0, f"note: {src} is not written by nearlight: kept as it was")
        _write_verdict(tmp, out, result, reason, command)
        record(tmp, command=command, entry_modules=[__name__], part="verdict")

    try:
        write_folder(out, fill, existing=check_baseline_folder)
    except _Refused:
        return result
    result.replaced = True
    return result


def _entries(folder: Path) -> list[str]:
    """The names at the top of ``folder`` (none when it does not exist)."""
    return [p.name for p in folder.iterdir()] if folder.is_dir() else []


def _write_verdict(folder: Path, out: Path, result: Regenerated, reason: str | None, command: str) -> None:
    """``verdict.json`` and ``verdict.md`` in ``folder``: the lines that are not ``same``, the summary, the reason."""
    before = _code_version_of(out)  # None for a first baseline
    summary = result.lines[-1]
    changed = [c for c in result.checks if c.verdict in ("worse", "missing", "better")]
    doc = {
        "format": VERDICT_FORMAT,
        "command": command,
        "made": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "code_version": code_version(),
        "replaced_code_version": before,
        "summary": summary,
        "counts": verdict_counts(result.checks),
        "reason": reason,
        "changed": [c.line().strip() for c in changed],
    }
    write_json(folder / VERDICT_JSON, doc, what="the baseline's verdict")
    lines = [
        "# Verdict of this baseline against the one it replaced",
        "",
        f"Made by `{command}` at {doc['code_version']} ({doc['made']}), replacing the baseline made at "
        f"{before or '(none: a first baseline)'}.",
        "",
        f"Summary: {summary}",
        "",
        f"Reason given for what got worse: {reason}" if reason else "No reason given (nothing got worse).",
        "",
    ]
    if changed:
        lines += ["Every check that is not `same`:", "", "```", *doc["changed"], "```", ""]
    write_text(folder / VERDICT_MD, "\n".join(lines), what="the baseline's verdict")


def _code_version_of(folder: Path) -> str | None:
    """The commit that made a results folder's rows (its provenance record's ``results`` part), if recorded."""
    try:
        doc = json.loads((folder / PROVENANCE).read_text(encoding="utf-8"))
        return str(doc["parts"]["results"]["code_version"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def read_verdict(folder: str | Path) -> dict[str, Any]:
    """The ``verdict.json`` of a baseline folder.

    Raises
    ------
    UserError
        Absent, not JSON, or not a verdict record.
    """
    path = Path(folder) / VERDICT_JSON
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError:
        raise UserError(f"{path}: missing: regenerate the baseline with `nearlight baseline`, which writes it") from None
    except ValueError:
        raise UserError(f"{path}: not valid JSON: regenerate the baseline with `nearlight baseline`") from None
    if not isinstance(doc, dict) or doc.get("format") != VERDICT_FORMAT:
        raise UserError(f"{path}: expected a verdict record ({VERDICT_FORMAT})")
    return doc
