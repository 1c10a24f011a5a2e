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
import re
from pathlib import Path
from typing import Any

import pandas as pd

from ...errors import UserError, one_line
from ...files.atomic import atomic_write, cannot_write, write_json
from .environment import collect

RESULTS = "results.parquet"
SWEEP_JSON = "sweep.json"
ENVIRONMENT = "environment.json"
PARTS = "parts"
RENDERS = "renders"


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
            raise cannot_write(self.out, exc) from None
        manifest = self.out / SWEEP_JSON
        doc = {"format": "nearlight-sweep/1", "name": name, "sweep_hash": sweep_hash, "tasks": n_tasks, "axes": list(axes)}
        if manifest.is_file():
            old = read_sweep_json(self.out)
            if old.get("sweep_hash") != sweep_hash:
                raise UserError(
                    f"{self.out}: holds results of another sweep ({old.get('name')!r}, hash {old.get('sweep_hash')}); "
                    "choose another --out or remove it"
                )
        else:
            write_json(manifest, doc)
        self.n_tasks = n_tasks
        self._record_environment()

    def _record_environment(self) -> None:
        """Add this process's environment to ``environment.json`` unless an identical record is there."""
        envs = read_environments(self.out)
        here = collect()
        if here not in envs:
            envs.append(here)
            write_json(self.out / ENVIRONMENT, envs)

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
    fix = "move it aside: the next `nearlight sweep` into this folder records its environment again"
    try:
        envs = json.loads(path.read_bytes().decode("utf-8"))
    except ValueError as exc:
        raise _damaged(path, f"not valid JSON: {one_line(exc)[:80]}", fix) from None
    if not (isinstance(envs, list) and all(isinstance(e, dict) for e in envs)):
        raise _damaged(path, "expected a JSON list of environment records", fix)
    return envs


#: Columns every part must have (the rest depend on the sweep's axes).
REQUIRED_COLUMNS = ("task_id", "task_index", "status")


def _damaged(path: Path, why: str, fix: str) -> UserError:
    return UserError(f"{path}: damaged ({why}); {fix}")


def _first_sentence(exc: BaseException) -> str:
    """The first sentence of an exception's message, without the file name it repeats."""
    text = one_line(exc)
    text = re.sub(r"^Could not open Parquet input source '[^']*': ", "", text)
    return re.split(r"(?<=\.) ", text, maxsplit=1)[0][:160].rstrip(".")


def _read_frame(path: Path, *, fix: str) -> pd.DataFrame:
    """One Parquet file with the required columns, or a :class:`UserError` naming it."""
    import pyarrow

    try:
        df = pd.read_parquet(path)
    except (OSError, ValueError, pyarrow.ArrowException) as exc:
        raise _damaged(path, f"not a readable Parquet file: {_first_sentence(exc)}", fix) from None
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise _damaged(path, f"column {missing[0]} missing", fix)
    return df


def _part_fix(path: Path) -> str:
    return (f"delete it, or run the same `nearlight sweep` or `nearlight score` again: it moves the damaged part "
            f"to {PARTS}/damaged/ and recomputes task {path.stem}")


def read_parts(out: str | os.PathLike) -> pd.DataFrame:
    """Every part's row, in task order (an empty frame when none).

    Raises
    ------
    UserError
        Naming the first damaged part (unreadable, or without the required columns).
    """
    parts = sorted((Path(out) / PARTS).glob("*.parquet"))
    if not parts:
        return pd.DataFrame()
    frames = []
    for p in parts:
        df = _read_frame(p, fix=_part_fix(p))
        if len(df) != 1 or str(df["task_id"].iloc[0]) != p.stem:
            raise _damaged(p, f"expected one row for task {p.stem}, got {len(df)}", _part_fix(p))
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values("task_index", kind="stable").reset_index(drop=True)


def set_aside_damaged_parts(out: str | os.PathLike) -> list[Path]:
    """Move every damaged part of a results folder to ``parts/damaged/`` so its task runs again.

    A part is damaged when it is not a readable Parquet file with one row of
    its task (see :func:`read_parts`). Nothing is deleted: the damaged files
    are kept for a person to look at, and good parts are never touched.

    Returns
    -------
    list of Path
        Where the damaged parts went.
    """
    moved = []
    folder = Path(out) / PARTS
    for p in sorted(folder.glob("*.parquet")):
        try:
            df = _read_frame(p, fix="")
            ok = len(df) == 1 and str(df["task_id"].iloc[0]) == p.stem
        except UserError:
            ok = False
        if not ok:
            (folder / "damaged").mkdir(exist_ok=True)
            target = folder / "damaged" / p.name
            n = 1
            while target.exists():
                target = folder / "damaged" / f"{p.stem}.{n}.parquet"
                n += 1
            os.replace(p, target)
            moved.append(target)
    return moved


def read_sweep_json(out: str | os.PathLike) -> dict[str, Any]:
    """The ``sweep.json`` of a results folder.

    Raises
    ------
    UserError
        It is not a JSON object with ``name``, ``sweep_hash`` and ``tasks``.
    """
    path = Path(out) / SWEEP_JSON
    fix = ("it records which sweep the folder holds: restore it, or move it aside and run the same "
           "`nearlight sweep` again (finished parts are kept)")  # fmt: skip
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise _damaged(path, f"not valid JSON: {one_line(exc)[:80]}", fix) from None
    if not isinstance(doc, dict):
        raise _damaged(path, "expected a JSON object", fix)
    for key, kind in (("name", str), ("sweep_hash", str), ("tasks", int)):
        if not isinstance(doc.get(key), kind) or isinstance(doc.get(key), bool):
            raise _damaged(path, f"{key}: expected {'a string' if kind is str else 'an integer'}", fix)
    if not isinstance(doc.get("axes", []), list):
        raise _damaged(path, "axes: expected a list", fix)
    return doc


def read_results(out: str | os.PathLike) -> tuple[pd.DataFrame, bool]:
    """The rows of a sweep folder and whether the sweep is complete.

    Reads ``results.parquet`` when present, else the parts of an unfinished run.

    Raises
    ------
    UserError
        When the folder holds no results, or a results file is damaged (the
        message names it and says what to do).
    """
    out = Path(out)
    if not out.is_dir():
        raise UserError(f"{out}: not a sweep results folder (expected a folder written by `nearlight sweep`)")
    if (out / RESULTS).is_file():
        fix = f"remove it and run the same `nearlight sweep` again: it is rebuilt from {PARTS}/"
        return _read_frame(out / RESULTS, fix=fix), True
    df = read_parts(out)
    if df.empty:
        raise UserError(f"{out}: no sweep results (expected {RESULTS} or {PARTS}/*.parquet from `nearlight sweep`)")
    return df, False
