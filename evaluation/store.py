"""Results on disk: one Parquet part per finished task, consolidated at the end.

Layout of a sweep's output folder::

    DIR/sweep.json          what ran: sweep name, hash of its task list, task count
    DIR/environment.json    where it ran: a list of environments (packages, CPU, Mitsuba
                            variant, commit), one per distinct machine that ran tasks
    DIR/parts/<id>.parquet  one row per finished task, written atomically (temp + rename)
    DIR/results.parquet     every row in task order, written only when every task has its row
    DIR/renders/            the render cache (mitsuba renderer)

A part is named by its task's stable id, so a re-run skips finished tasks and
can never write a task twice; a killed run leaves only whole parts behind.
``results.parquet`` exists only for a complete sweep: nothing partial looks
finished.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd

from nearlight.errors import UserError

RESULTS = "results.parquet"
MANIFEST = "sweep.json"
ENVIRONMENT = "environment.json"
PARTS = "parts"


def atomic_write(path: Path, write: Any) -> None:
    """Call ``write(tmp)`` on a temporary sibling of ``path``, then rename it onto ``path`` (never half a file)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ResultStore:
    """The results folder of one sweep.

    Parameters
    ----------
    out : path-like
        Output folder (created).
    name, sweep_hash : str
        The sweep's name and task-list hash; a folder holding another sweep's
        results is refused.
    n_tasks : int
    axes : list of str
        The sweep's axis names (config columns), for the report.
    """

    def __init__(self, out: str | os.PathLike, *, name: str, sweep_hash: str, n_tasks: int, axes: list[str] = ()):
        self.out = Path(out)
        try:
            (self.out / PARTS).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.out}: cannot write there ({exc.strerror or exc})") from None
        manifest = self.out / MANIFEST
        doc = {"format": "nearlight-sweep/1", "name": name, "sweep_hash": sweep_hash, "tasks": n_tasks, "axes": list(axes)}
        if manifest.is_file():
            old = json.loads(manifest.read_text())
            if old.get("sweep_hash") != sweep_hash:
                raise UserError(
                    f"{self.out}: holds results of another sweep ({old.get('name')!r}, hash {old.get('sweep_hash')}); "
                    "choose another --out or remove it"
                )
        else:
            atomic_write(manifest, lambda tmp: Path(tmp).write_text(json.dumps(doc, indent=2) + "\n"))
        self.n_tasks = n_tasks
        self._record_environment()

    def _record_environment(self) -> None:
        """Add this process's environment to ``environment.json`` unless an identical record is there."""
        from nearlight.evaluation.environment import collect

        envs = read_environments(self.out)
        here = collect()
        if here not in envs:
            envs.append(here)
            text = json.dumps(envs, indent=2) + "\n"
            atomic_write(self.out / ENVIRONMENT, lambda tmp: Path(tmp).write_text(text))

    @property
    def cache_dir(self) -> Path:
        """The render cache folder."""
        return self.out / "renders"

    def done_ids(self) -> set[str]:
        """Ids of the tasks whose row is on disk."""
        return {p.stem for p in (self.out / PARTS).glob("*.parquet")}

    def write_row(self, row: dict[str, Any]) -> None:
        """Write one finished task's row (atomically) as ``parts/<task_id>.parquet``."""
        path = self.out / PARTS / f"{row['task_id']}.parquet"
        atomic_write(path, lambda tmp: pd.DataFrame([row]).to_parquet(tmp, index=False))

    def consolidate(self) -> pd.DataFrame | None:
        """Write ``results.parquet`` if every task has its row; return the table, or None if incomplete."""
        df = read_parts(self.out)
        target = self.out / RESULTS
        if len(df) != self.n_tasks:
            target.unlink(missing_ok=True)
            return None
        atomic_write(target, lambda tmp: df.to_parquet(tmp, index=False))
        return df


def read_environments(out: str | os.PathLike) -> list[dict[str, Any]]:
    """The environment records of a results folder (empty when it has none).

    Raises
    ------
    UserError
        When ``environment.json`` is not a JSON list of records.
    """
    path = Path(out) / ENVIRONMENT
    if not path.is_file():
        return []
    try:
        envs = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: damaged ({exc}); delete it, the next run writes it again") from None
    if not (isinstance(envs, list) and all(isinstance(e, dict) for e in envs)):
        raise UserError(f"{path}: expected a JSON list of environment records; delete it, the next run writes it again")
    return envs


def read_parts(out: str | os.PathLike) -> pd.DataFrame:
    """Every part's row, in task order (an empty frame when none)."""
    parts = sorted((Path(out) / PARTS).glob("*.parquet"))
    if not parts:
        return pd.DataFrame()
    df = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    return df.sort_values("task_index", kind="stable").reset_index(drop=True)


def read_results(out: str | os.PathLike) -> tuple[pd.DataFrame, bool]:
    """The rows of a sweep folder and whether the sweep is complete.

    Reads ``results.parquet`` when present, else the parts of an unfinished run.

    Raises
    ------
    UserError
        When the folder holds no results.
    """
    out = Path(out)
    if (out / RESULTS).is_file():
        return pd.read_parquet(out / RESULTS), True
    df = read_parts(out)
    if df.empty:
        raise UserError(f"{out}: no sweep results (expected {RESULTS} or {PARTS}/*.parquet from `nearlight sweep`)")
    return df, False
