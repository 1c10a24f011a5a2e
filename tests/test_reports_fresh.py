"""Every committed report describes the code in this checkout (nearlight.evaluation.engine.provenance).

A report under ``reports/`` records the command that made it and the content
hash of every nearlight source file in the import closure of that command
(``provenance.json``). When any of those files changes, the report is stale:
this test fails and names the files and the command that regenerates it.
Regression baselines (``*-baseline``) are held to the same rule: a baseline
older than the code it pins cannot tell today's regression from one that was
there when it was made. Regenerate one with ``nearlight baseline`` (its
verdict against the old baseline is written beside it and checked by
tests/evaluation/views/test_smoke_baseline.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from nearlight.evaluation.engine import provenance

REPORTS = Path(__file__).resolve().parent.parent / "reports"
#: ``references/`` holds runs kept from other machines, not regenerated here: a kept table retires when
#: its code changes (``nearlight.evaluation.paper.references``, ``tests/evaluation/paper/test_references.py``).
FOLDERS = sorted(p for p in REPORTS.iterdir() if p.is_dir() and p.name != "references")


def test_there_are_committed_reports():
    assert len(FOLDERS) >= 3, FOLDERS


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: p.name)
def test_committed_report_was_made_by_the_code_in_this_checkout(folder):
    stale = provenance.stale(folder)
    assert not stale, f"reports/{folder.name} is stale:\n" + "\n".join(stale)
