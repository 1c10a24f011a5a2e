"""This machine's build and scores of ``suites/crosscheck-v1.yaml`` against those kept from other CPUs.

Built suites are not shipped, so every user renders them on their own CPU:
the test suite builds the small Mitsuba suite here (the portable LLVM target,
unless the machine cannot run it), scores it with a continuous method
(``full``) and a brightest-pixel one (``paper-init``), and compares each with
every kept reference whose code is today's (``reports/references/scores/``,
:mod:`nearlight.evaluation.suites.references`): the build within the suite's
digest tolerance (``suite verify --against``), the scores by ``nearlight
compare`` (no check worse or missing). A failure names both machines.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nearlight.cli import main
from nearlight.evaluation.paper.check import machine
from nearlight.evaluation.suites import references as kept
from nearlight.evaluation.suites.suite import MANIFEST, verify_against
from nearlight.evaluation.views.compare import compare_dirs

ROOT = Path(__file__).resolve().parents[3]
SUITE = ROOT / "suites" / "crosscheck-v1.yaml"
METHODS = ("full", "paper-init")
REFERENCES = [r[0] for r in kept.references(SUITE, "crosscheck-v1")]


@pytest.fixture(scope="module")
def here(tmp_path_factory):
    """This machine's build of the suite and its scores: ``{"build": Path, method: Path}``."""
    pytest.importorskip("mitsuba")
    d = tmp_path_factory.mktemp("crosscheck")
    assert main(["suite", "build", str(SUITE), "--out", str(d / "build"), "--quiet", "--no-cache", "--workers", "2"]) == 0
    out = {"build": d / "build"}
    for m in METHODS:
        assert main(["score", str(d / "build"), "--method", m, "--out", str(d / m), "--quiet", "--workers", "2"]) == 0
        out[m] = d / m
    return out


def _reference(name):
    (_, folder, record, live), = [r for r in kept.references(SUITE, "crosscheck-v1") if r[0] == name]
    if not live:
        pytest.skip(f"reference {name}: its code or suite file changed since it was kept "
                    f"(made by {record['made_by']}); delete it")
    return folder, record


def _machines(here, folder):
    manifests = [json.loads((p / MANIFEST).read_text()) for p in (here["build"], folder)]
    return "this build on {} against the reference built on {}".format(*(machine(m) for m in manifests))


def test_a_reference_is_kept():
    assert REFERENCES


@pytest.mark.parametrize("name", REFERENCES)
def test_this_build_agrees_with_a_kept_build(here, name):
    folder, _ = _reference(name)
    mine, theirs = (json.loads((p / MANIFEST).read_text()) for p in (here["build"], folder))
    verdicts = verify_against(mine, theirs)
    differs = [text for verdict, text in verdicts if verdict == "differs"]
    assert not differs and len(verdicts) == len(theirs["cases"]), f"{_machines(here, folder)}: {differs}"


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", REFERENCES)
def test_these_scores_agree_with_kept_scores(here, name, method):
    folder, record = _reference(name)
    assert method in record["methods"]
    checks, lines = compare_dirs(here[method], folder / method)
    bad = [c.line() for c in checks if c.regression]
    assert not bad, f"{method}: {_machines(here, folder)}:\n" + "\n".join(bad)
    assert checks and lines[-1].startswith("ok: nothing worse")
