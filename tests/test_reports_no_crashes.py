"""No committed report holds a task that crashed.

A task's row has ``status`` ``ok``, ``failed`` (the method said it cannot
answer, and why) or ``error`` (an exception stopped it: ``"<stage>: <type>:
<message> (<file>:<line>)"``, ``evaluation.engine.tasks.failed_row``). An
``error`` from nearlight's ``UserError`` is a stated refusal (a method's option
that cannot reach the lamp, say); any other exception type is a bug that a
table would otherwise show as a missing number: at 45b2da5 the realism study
held 10 rows of ``estimate: LinAlgError: Singular matrix`` (the sphere fit on
exactly planar range points), which no test saw. Every ``results.parquet``
under ``reports/`` (references too: a kept run's crash is as much a bug).
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

REPORTS = Path(__file__).resolve().parent.parent / "reports"
RESULTS = sorted(REPORTS.rglob("results.parquet"))
#: ``<stage>: <ExceptionType>:`` at the start of an error row's message.
KIND = re.compile(r"^(\w+): (\w+):")


def test_there_are_results():
    assert len(RESULTS) >= 10, RESULTS


@pytest.mark.parametrize("path", RESULTS, ids=lambda p: str(p.parent.relative_to(REPORTS)))
def test_no_task_crashed(path):
    rows = pd.read_parquet(path, columns=["status", "error"])
    errors = rows.loc[rows["status"] == "error", "error"].astype(str)
    kinds = [KIND.match(e) for e in errors]
    assert all(kinds), f"{path}: error rows without a '<stage>: <type>:' message: {errors[[not k for k in kinds]][:3].tolist()}"
    crashed = [e for e, k in zip(errors, kinds) if k.group(2) != "UserError"]
    assert not crashed, f"{path.relative_to(REPORTS)}: {len(crashed)} task(s) crashed, e.g. {crashed[0]}"
