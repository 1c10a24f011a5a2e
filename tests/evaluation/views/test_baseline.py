"""``nearlight baseline``: a baseline is replaced only with its verdict against the old one, in writing.

Analytic 24x18 captures (no Mitsuba): a first baseline, a regeneration with
nothing worse, a planted regression refused without a reason (the old
baseline left byte for byte) and accepted with one, and ``compare``'s warning
on a baseline older than the code it pins.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd
import yaml

from nearlight.cli import main
from nearlight.evaluation.engine import provenance
from nearlight.evaluation.views.baseline import read_verdict
from nearlight.evaluation.views.compare import compare_dirs

SWEEP = {
    "name": "tiny",
    "renderer": "analytic",
    "scene": {"width": 24, "height": 18},
    "axes": {"lamp_distance": [0.3, 0.5]},
    "seeds": 1,
    "methods": ["paper-init"],
}
#: paper-init with its lamp moved 5 % further along the ray, under its own name: a planted regression.
WORSE = {"name": "paper-init", "method": "nearlight.evaluation.planted:further_along_ray",
         "options": {"base": "paper-init", "fraction": 0.05}}  # fmt: skip


def _sweep(folder: Path, **changes) -> Path:
    path = folder / "sweep.yaml"
    path.write_text(yaml.safe_dump(SWEEP | changes))
    return path


def _digests(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def _baseline(sweep: Path, out: Path, *extra: str) -> int:
    return main(["baseline", str(sweep), "--out", str(out), "--quiet", *extra])


def test_first_baseline_then_a_regeneration_with_nothing_worse(tmp_path, capsys):
    out = tmp_path / "tiny-baseline"
    assert _baseline(_sweep(tmp_path), out) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"{out}/verdict.md"
    verdict = read_verdict(out)
    assert verdict["replaced_code_version"] is None and verdict["reason"] is None and verdict["changed"] == []
    assert not (out / "renders").exists() and not (out / "parts").exists()
    parts = json.loads((out / provenance.FILE).read_text())["parts"]
    assert set(parts) == {"results", "report", "verdict"}
    assert "nearlight/evaluation/views/baseline.py" not in parts["results"]["code"]  # the run's code is the run's
    assert "evaluation/views/compare.py" in parts["verdict"]["code"]
    assert not provenance.stale(out)

    (out / "README.md").write_text("# Our baseline\n")  # the project's own file: carried over, never deleted
    (out / "notes").mkdir()
    (out / "notes" / "why.txt").write_text("made for the paper\n")
    assert _baseline(_sweep(tmp_path), out) == 0
    assert (out / "README.md").read_text() == "# Our baseline\n"
    assert (out / "notes" / "why.txt").read_text() == "made for the paper\n"
    assert "note: " + str(out / "README.md") + " is not written by nearlight: kept as it was" in capsys.readouterr().out
    assert ".partial" not in (out / "verdict.md").read_text()  # the new run is named as such, not by its staging place
    verdict = read_verdict(out)
    assert verdict["counts"]["worse"] == verdict["counts"]["missing"] == 0 and verdict["counts"]["same"] > 0
    assert verdict["replaced_code_version"] == verdict["code_version"]
    assert "No reason given" in (out / "verdict.md").read_text()


def test_a_worse_run_replaces_the_baseline_only_with_a_reason(tmp_path, capsys):
    out = tmp_path / "tiny-baseline"
    assert _baseline(_sweep(tmp_path), out) == 0
    before = _digests(out)
    capsys.readouterr()

    assert _baseline(_sweep(tmp_path, methods=[WORSE]), out) == 1
    captured = capsys.readouterr()
    assert "worse" in captured.out and "nothing replaced" in captured.err and "--reason" in captured.err
    assert _digests(out) == before  # the old baseline, byte for byte
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no staging folder left

    reason = "planted: paper-init 5 % further along the ray, to test the verdict record"
    assert _baseline(_sweep(tmp_path, methods=[WORSE]), out, "--reason", reason) == 0
    verdict = read_verdict(out)
    assert (pd.read_parquet(out / "results.parquet")["status"] == "ok").all()  # worse numbers, not failures
    assert verdict["reason"] == reason and verdict["counts"]["worse"] > 0
    assert all("paper-init" in line for line in verdict["changed"])
    text = (out / "verdict.md").read_text()
    assert reason in text and "lamp_position_error_pct" in text


def test_compare_warns_when_the_baseline_is_older_than_its_code(tmp_path, capsys):
    out = tmp_path / "tiny-baseline"
    assert _baseline(_sweep(tmp_path), out) == 0
    _, lines = compare_dirs(out, out)
    assert not any(line.startswith("warning:") for line in lines)
    record = out / provenance.FILE
    doc = json.loads(record.read_text())
    doc["parts"]["results"]["code"]["estimator/first_stage.py"] = "0" * 64  # as if made by other code
    record.write_text(json.dumps(doc))
    _, lines = compare_dirs(out, out)
    warning = [line for line in lines if line.startswith("warning:")]
    assert len(warning) == 1 and "older than the code it pins" in warning[0], lines
    assert any("estimator/first_stage.py changed" in line for line in lines)
