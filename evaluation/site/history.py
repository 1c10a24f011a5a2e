"""History: each metric per run of a committed scorecard or baseline (its git history), or of several results
folders of one sweep, with the runs where ``nearlight compare`` says a metric got worse marked.

A **series** is the runs of one results folder in order: every commit that
changed a committed folder's ``results.parquet`` (oldest first; a score folder,
with ``scorecard.json``, or a baseline ``nearlight baseline`` made, with
``verdict.json``), or the results folders of one sweep given to ``nearlight
site`` (two or more with the same sweep name, in the order given). Each run is
summarised per method and metric by :func:`~nearlight.evaluation.suites.scorecard.median_ci`
over its rows (a failed row is a miss, as scorecards count it) and the count
of failed rows. A run is **marked** on a method's metric when
:func:`~nearlight.evaluation.views.compare.compare_dirs` of that run against
the run before it has a check of that method and metric that fails (``worse``
or ``missing``): asv's "Regressions", with nearlight's statistics.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..engine.store import read_results
from ..scoring.metrics import METRICS
from ..suites.scorecard import median_ci
from ..views.compare import compare_dirs

#: Files of a results folder that a run of the history reads (what ``compare`` reads).
RUN_FILES = ("results.parquet", "sweep.json", "environment.json", "scorecard.json")
#: The metrics a history draws (the table has every one of :data:`METRICS` but the run time, and ``failed``).
DRAWN = ("lamp_position_error_pct", "sigma_rel_error", "failed")


@dataclasses.dataclass(frozen=True)
class Run:
    """One run of a series: its label (a short commit, or a folder), its date, and its results folder."""

    label: str
    when: str
    folder: Path


@dataclasses.dataclass
class Series:
    """The runs of one results folder (or one sweep's folders) and their values.

    Attributes
    ----------
    name : str
        The folder (repository-relative) or the sweep's name.
    origin : str
        ``"git"`` (commits of a committed folder) or ``"folders"`` (results folders given).
    runs : list of Run
    points : DataFrame
        One row per run × method × metric: ``run`` (index into ``runs``), ``method``, ``metric``, ``value``,
        ``lo``, ``hi`` (the 95 % interval; NaN for ``failed``), ``worse`` (bool).
    """

    name: str
    origin: str
    runs: list[Run]
    points: pd.DataFrame


def summarise(folder: Path) -> pd.DataFrame:
    """Per method and metric of a results folder: the median with its interval, and the failed rows."""
    rows, _ = read_results(folder)
    out = []
    for method, g in rows.groupby("method", sort=True):
        ok = (g["status"] == "ok").to_numpy()
        for metric in METRICS:
            if metric == "runtime_s" or metric not in g:
                continue
            x = np.where(ok, pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float), np.nan)
            value, lo, hi = median_ci(x)
            out.append({"method": method, "metric": metric, "value": value, "lo": lo, "hi": hi})
        out.append({"method": method, "metric": "failed", "value": float((~ok).sum()), "lo": np.nan, "hi": np.nan})
    return pd.DataFrame(out)


def regressions(new: Path, base: Path) -> set[tuple[str, str]]:
    """``(method, metric)`` of every check of ``new`` against ``base`` that fails (``failures`` read as ``failed``)."""
    checks, _ = compare_dirs(new, base, intervals=False)
    return {(c.method, "failed" if c.metric == "failures" else c.metric) for c in checks if c.regression}


def series(name: str, origin: str, runs: Sequence[Run]) -> Series:
    """Summarise each run and mark it against the one before (:func:`regressions`)."""
    frames = []
    for i, run in enumerate(runs):
        got = summarise(run.folder).assign(run=i)
        marked = regressions(run.folder, runs[i - 1].folder) if i else set()
        got["worse"] = [(m, k) in marked for m, k in zip(got["method"], got["metric"])]
        frames.append(got)
    points = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return Series(name, origin, list(runs), points)


def _git(repo: Path, *args: str, binary: bool = False) -> Any:
    run = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, check=False)
    return run.stdout if binary else run.stdout.decode("utf-8", "replace")


def repository(folder: Path) -> Path | None:
    """The root of the git work tree holding ``folder`` (None: not in one, or git is not installed)."""
    if shutil.which("git") is None:
        return None
    top = _git(folder, "rev-parse", "--show-toplevel").strip()
    return Path(top) if top else None


class _Blobs:
    """Many ``COMMIT:PATH`` reads through one ``git cat-file --batch`` process."""

    def __init__(self, repo: Path):
        self.proc = subprocess.Popen(["git", "-C", str(repo), "cat-file", "--batch"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE)  # fmt: skip

    def read(self, spec: str) -> bytes | None:
        self.proc.stdin.write(spec.encode() + b"\n")
        self.proc.stdin.flush()
        header = self.proc.stdout.readline().split()
        if len(header) < 3 or header[1] != b"blob":
            return None
        data = self.proc.stdout.read(int(header[2]))
        self.proc.stdout.read(1)  # the newline after the content
        return data

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()
        self.proc.stdout.close()


def committed_folders(repo: Path, sources: Sequence[Path]) -> list[str]:
    """The repository-relative folders under ``sources`` whose history is drawn: a committed ``results.parquet``
    beside a ``scorecard.json`` (a score folder) or a ``verdict.json`` (a baseline), in the checkout."""
    out = []
    for line in _git(repo, "ls-files", "--", *map(str, sources)).splitlines():
        path = Path(line)
        if path.name == "results.parquet" and any((repo / path.parent / f).is_file() for f in ("scorecard.json",
                                                                                                 "verdict.json")):
            out.append(path.parent.as_posix())
    return sorted(out)


def git_series(repo: Path, folders: Sequence[str]) -> list[Series]:
    """The series of each committed folder changed by two commits or more: every commit that changed its
    ``results.parquet``, oldest first, each read into a temporary folder while it is summarised and compared
    (the runs' folders are gone on return)."""
    blobs = _Blobs(repo)
    with tempfile.TemporaryDirectory(prefix="nearlight-site-") as tmp:
        try:
            out = []
            for k, folder in enumerate(folders):
                log = _git(repo, "log", "--reverse", "--format=%H %cs", "--", f"{folder}/results.parquet").split("\n")
                runs = []
                for line in filter(None, log):
                    commit, when = line.split()
                    where = Path(tmp) / f"{k}" / commit[:12]
                    where.mkdir(parents=True)
                    for name in RUN_FILES:
                        data = blobs.read(f"{commit}:{folder}/{name}")
                        if data is not None:
                            (where / name).write_bytes(data)
                    if (where / "results.parquet").is_file() and (where / "sweep.json").is_file():
                        runs.append(Run(commit[:7], when, where))
                if len(runs) > 1:  # one run has no history (a kept reference, a folder committed once)
                    out.append(series(folder, "git", runs))
            return out
        finally:
            blobs.close()


def history_json(all_series: Sequence[Series]) -> dict[str, Any]:
    """Every series as JSON (``nearlight-site-history/1``): runs and points, a non-finite value as null."""

    def num(x: Any) -> float | None:
        return float(x) if x is not None and np.isfinite(x) else None

    return {"format": "nearlight-site-history/1", "series": [
        {"name": s.name, "origin": s.origin, "runs": [{"label": r.label, "when": r.when} for r in s.runs],
         "points": [{"run": int(p.run), "method": p.method, "metric": p.metric, "value": num(p.value), "lo": num(p.lo),
                     "hi": num(p.hi), "worse": bool(p.worse)} for p in s.points.itertuples()]}
        for s in all_series]}  # fmt: skip


def folder_series(folders: Sequence[Path]) -> list[Series]:
    """Two or more results folders of one sweep (same ``sweep.json`` name), in the order given: a series."""
    by_name: dict[str, list[Path]] = {}
    for f in folders:
        try:
            name = json.loads((f / "sweep.json").read_text(encoding="utf-8")).get("name")
        except (OSError, ValueError, AttributeError):
            continue
        if isinstance(name, str) and (f / "results.parquet").is_file():
            by_name.setdefault(name, []).append(f)
    return [series(name, "folders", [Run(f.name, "", f) for f in fs]) for name, fs in by_name.items() if len(fs) > 1]
