"""Provenance records: the import closure they hash, and staleness detection (nearlight.evaluation.engine.provenance)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nearlight.evaluation.engine import provenance


@pytest.fixture
def fake_package(tmp_path, monkeypatch):
    """A three-module package standing in for nearlight: a imports b at call time, c is unused."""
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("__version__ = '0'\n")
    (root / "sub" / "__init__.py").write_text("")
    (root / "sub" / "a.py").write_text("def f():\n    from . import b\n    return b.g()\n")
    (root / "sub" / "b.py").write_text("import importlib\nX = importlib.import_module('nearlight.sub.d')\ndef g():\n    return 1\n")
    (root / "sub" / "c.py").write_text("import numpy\n")
    (root / "sub" / "d.py").write_text("from ..sub.b import g  # cycle back to b\n")
    monkeypatch.setattr(provenance, "PACKAGE_ROOT", root)
    return root


def _names(paths, root):
    return [p.relative_to(root).as_posix() for p in paths]


def test_closure_follows_function_level_relative_and_string_imports(fake_package):
    deps = provenance.dependencies(["nearlight.sub.a"])
    assert _names(deps, fake_package) == ["__init__.py", "sub/__init__.py", "sub/a.py", "sub/b.py", "sub/d.py"]


def test_closure_of_the_real_engine_has_the_stages_it_runs_and_not_the_cli():
    deps = _names(provenance.dependencies(["nearlight.evaluation.engine.run"]), provenance.PACKAGE_ROOT)
    for needed in ("estimator/paper.py", "physics/reflectance.py", "generator/render.py", "evaluation/engine/tasks.py"):
        assert needed in deps
    assert "cli.py" not in deps and "estimator/plot.py" not in deps


def test_stale_names_the_changed_code_and_input_and_the_command(fake_package, tmp_path):
    sweep = fake_package / "s.yaml"
    sweep.write_text("name: s\n")
    out = tmp_path / "out"
    out.mkdir()
    provenance.record(out, command="nearlight sweep s.yaml --out out", entry_modules=["nearlight.sub.a"], inputs=[sweep])
    assert provenance.stale(out) == []
    (fake_package / "sub" / "c.py").write_text("# not a dependency\n")
    assert provenance.stale(out) == []
    (fake_package / "sub" / "b.py").write_text("def g():\n    return 2\n")
    sweep.write_text("name: t\n")
    [line] = provenance.stale(out)
    assert "sub/b.py changed" in line and "s.yaml changed" in line and "nearlight sweep s.yaml --out out" in line


def test_a_new_run_drops_the_old_report_part(fake_package, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    provenance.record(out, command="run", entry_modules=["nearlight.sub.a"])
    provenance.record(out, command="view", entry_modules=["nearlight.sub.c"], part="report")
    assert set(json.loads((out / provenance.FILE).read_text())["parts"]) == {"results", "report"}
    provenance.record(out, command="run again", entry_modules=["nearlight.sub.a"])
    assert set(json.loads((out / provenance.FILE).read_text())["parts"]) == {"results"}


def test_missing_record_is_stale(tmp_path):
    assert "missing" in provenance.stale(tmp_path)[0]


def test_records_below_the_folder_are_checked_too(fake_package, tmp_path):
    """A reproduction: its report records itself, each experiment's results folder the run that made its rows."""
    out = tmp_path / "out"
    (out / "sweeps" / "board").mkdir(parents=True)
    provenance.record(out, command="reproduce", entry_modules=["nearlight.sub.c"], part="report")
    provenance.record(out / "sweeps" / "board", command="reproduce", entry_modules=["nearlight.sub.a"])
    assert provenance.stale(out) == []
    (fake_package / "sub" / "a.py").write_text("def f():\n    return 3\n")
    [line] = provenance.stale(out)
    assert line.startswith("sweeps/board: results: sub/a.py changed")


def test_code_is_hashed_without_comments_and_docstrings(tmp_path):
    """Tidying costs no regeneration: a docstring or comment edit in estimator/full.py keeps its code hash, a
    changed constant or line of code does not (the freshness test then names the file)."""
    from nearlight.evaluation.engine.provenance import code_hash

    src = (Path(provenance.PACKAGE_ROOT) / "estimator" / "full.py").read_text(encoding="utf-8")
    assert '"""Method ``full``' in src and "REFIT_EVIDENCE = 50.0" in src  # the edits below find their text

    def hashed(text: str) -> str:
        path = tmp_path / "full.py"
        path.write_text(text, encoding="utf-8")
        return code_hash(path)

    base = hashed(src)
    assert hashed(src.replace('"""Method ``full``', '"""Method ``full``, tidied', 1)) == base
    assert hashed(src.replace("\n\n\n", "\n\n\n# a new comment\n\n", 1)) == base
    assert hashed(src.replace("REFIT_EVIDENCE = 50.0", "REFIT_EVIDENCE = 51.0")) != base
    assert hashed(src.replace("REFIT_EVIDENCE = 50.0", "REFIT_EVIDENCE = 50.0  # why")) == base
    assert hashed(src.replace('f"', 'rf"', 1)) != base  # a string that is code, not a docstring, counts
