"""Results files (``nearlight-results/1``): a method's answers from elsewhere, checked and scored like a plug-in's.

On the tiny analytic suite of ``test_build`` (6 cases, 32x24): ``score --results`` on the file that
``score --method full`` wrote gives the same scorecard in every number but run time and machine (the
issue's bar, also measured on core-v1 in the closing note); ``--check`` refuses, naming the line, a missing
case, an extra case, a NaN, millimetres and a covariance that is not positive definite; an export holds no
truth anywhere and its checksums verify.
"""

from __future__ import annotations

import json
from pathlib import Path

import OpenEXR
import pytest

from nearlight.cli import main
from nearlight.evaluation.suites.results_file import SCALE_MAX
from nearlight.evaluation.suites.suite import read_manifest

from .test_build import N_CASES, write_suite

#: Keys of a scorecard that may differ between a method run here and its answers scored from a results file.
RUN_KEYS = {"wall_s", "runtime_s", "machine", "self_reported", "code_version"}


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """A built tiny suite and `full` scored on it (its results.jsonl beside the scorecard)."""
    root = tmp_path_factory.mktemp("results")
    assert main(["suite", "build", str(write_suite(root)), "--out", str(root / "built"), "--quiet", "--no-cache"]) == 0
    assert main(["score", str(root / "built"), "--method", "full", "--out", str(root / "full"), "--quiet"]) == 0
    return root / "built", root / "full"


def _lines(path: Path) -> list[dict]:
    return [json.loads(s) for s in path.read_text().splitlines()]


def _write(path: Path, lines: list) -> Path:
    path.write_text("\n".join(s if isinstance(s, str) else json.dumps(s) for s in lines) + "\n")
    return path


def test_results_file_of_full_scores_as_full_itself(scored, tmp_path):
    built, full = scored
    lines = _lines(full / "results.jsonl")
    assert lines[0]["format"] == "nearlight-results/1" and lines[0]["method"] == "full"
    assert lines[0]["rules"] == {"separation": "projected"}  # full's own separation, which its rules observe with
    assert [r["case"] for r in lines[1:]] == [c["id"] for c in read_manifest(built)["cases"]]
    assert main(["score", str(built), "--results", str(full / "results.jsonl"), "--out", str(tmp_path / "r"),
                 "--quiet"]) == 0  # fmt: skip
    mine, theirs = (json.loads((d / "scorecard.json").read_text()) for d in (full, tmp_path / "r"))
    assert {k: v for k, v in mine.items() if k not in RUN_KEYS} == {k: v for k, v in theirs.items() if k not in RUN_KEYS}
    assert theirs["self_reported"]["method_version"] == lines[0]["method_version"]
    assert theirs["runtime_s"]["total"] == pytest.approx(sum(r["runtime_s"] for r in lines[1:]), rel=1e-12)
    assert "**Self-reported**" in (tmp_path / "r" / "scorecard.md").read_text()
    assert not (tmp_path / "r" / "results.jsonl").exists()  # a results file is scored, not rewritten


def test_a_row_the_rules_refuse_fails_as_it_would_for_a_plug_in(scored, tmp_path):
    """A lamp behind the surface is no syntax error (`--check` passes it) but no number either: `in-front`."""
    built, full = scored
    lines = _lines(full / "results.jsonl")
    row = lines[1]
    cam = json.loads((built / read_manifest(built)["cases"][0]["path"] / "input" / "capture.json").read_text())
    row["lamp_position"] = [row["lamp_position"][0], row["lamp_position"][1], -0.3]  # below the z = 0 board
    row.pop("covariance", None)
    path = _write(tmp_path / "behind.jsonl", lines)
    assert cam["camera"]["position"][2] > 0
    assert main(["score", str(built), "--check", str(path)]) == 0
    assert main(["score", str(built), "--results", str(path), "--out", str(tmp_path / "r"), "--quiet"]) == 0
    card, before = (json.loads((d / "scorecard.json").read_text()) for d in (tmp_path / "r", full))
    assert lines[1]["status"] == "ok" and card["failed"] == before["failed"] + 1
    assert any("in-front" in e for e in card["errors"])


def _refusal(built: Path, path: Path, capsys) -> str:
    capsys.readouterr()
    assert main(["score", str(built), "--check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_check_names_the_first_bad_line(scored, tmp_path, capsys):
    built, full = scored
    good = _lines(full / "results.jsonl")
    ids = [r["case"] for r in good[1:]]

    missing = _refusal(built, _write(tmp_path / "m.jsonl", good[:-1]), capsys)
    assert f"case {ids[-1]}" in missing and "has no row" in missing

    extra = _refusal(built, _write(tmp_path / "e.jsonl", [*good, {**good[1], "case": "0123456789abcdef"}]), capsys)
    assert f"e.jsonl:{N_CASES + 2}: case 0123456789abcdef: not a case of suite" in extra

    twice = _refusal(built, _write(tmp_path / "t.jsonl", [*good, good[2]]), capsys)
    assert f"t.jsonl:{N_CASES + 2}: case {ids[1]}: a second row" in twice

    ok = [i for i, r in enumerate(good) if i and r["status"] == "ok"]  # lines (0: the header) with an answer
    assert len(ok) >= 2, "the tiny suite's full run needs two answered cases for these checks"
    nan = [json.dumps(r) for r in good]
    nan[ok[1]] = nan[ok[1]].replace('"sigma": ', '"sigma": NaN, "was": ', 1)
    assert "NaN: not a number" in _refusal(built, _write(tmp_path / "n.jsonl", nan), capsys)
    assert f"n.jsonl:{ok[1] + 1}" in _refusal(built, tmp_path / "n.jsonl", capsys)

    mm = [dict(r) for r in good]
    mm[ok[1]] = {**mm[ok[1]], "lamp_position": [1000 * x for x in mm[ok[1]]["lamp_position"]]}
    mm[ok[1]].pop("covariance", None)
    line = _refusal(built, _write(tmp_path / "mm.jsonl", mm), capsys)
    assert f"mm.jsonl:{ok[1] + 1}: case {ids[ok[1] - 1]}: lamp" in line and "millimetres?" in line
    assert f"{SCALE_MAX:g}" in line

    cov = [dict(r) for r in good]
    cov[1] = {**cov[1], "covariance": [[1e-4, 0, 0], [0, -1e-6, 0], [0, 0, 1e-4]]}
    line = _refusal(built, _write(tmp_path / "c.jsonl", cov), capsys)
    assert f"c.jsonl:2: case {ids[0]}: covariance" in line and "not positive definite" in line
    cov[1]["covariance"] = [[1e-4, 2e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]]
    assert "not symmetric" in _refusal(built, _write(tmp_path / "c.jsonl", cov), capsys)

    other = [{**good[0], "cases_hash": "ffffffffffffffff"}, *good[1:]]
    assert "m.jsonl" not in (line := _refusal(built, _write(tmp_path / "o.jsonl", other), capsys))
    assert "o.jsonl:1: cases_hash" in line

    failed = [dict(r) for r in good]
    failed[1] = {"case": ids[0], "status": "failed"}
    assert "needs its reason" in _refusal(built, _write(tmp_path / "f.jsonl", failed), capsys)
    failed[1]["reason"] = "no highlight"
    assert main(["score", str(built), "--check", str(_write(tmp_path / "f.jsonl", failed))]) == 0


def test_export_holds_no_truth_and_its_checksums_verify(scored, tmp_path, capsys):
    built, full = scored
    out = tmp_path / "inputs"
    assert main(["suite", "export", str(built), "--out", str(out)]) == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["format"] == "nearlight-suite-inputs/1" and len(doc["cases"]) == N_CASES
    keys: list[str] = []

    def walk(x):
        if isinstance(x, dict):
            keys.extend(map(str, x))
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)

    files = sorted(p for p in out.rglob("*") if p.is_file())
    assert {p.name for p in files} == {"manifest.json", "capture.json", "capture.exr"}
    assert len(files) == 1 + 2 * N_CASES
    for p in files:
        if p.suffix == ".json":
            walk(json.loads(p.read_text()))
        else:
            keys.extend(OpenEXR.InputFile(str(p)).header()["channels"])
    # (the noise record's camera-noise seed stays: it says how the noise was drawn, and without the clean
    # render it reveals nothing of the lamp or the surface)
    assert keys and not [k for k in keys if "truth" in k.lower() or k in ("generator", "categories", "lamp")]
    # the categories (e.g. the lamp distance) stay behind with the truth
    assert "lamp_distance" not in (out / "manifest.json").read_text()
    assert main(["score", str(out), "--check", str(full / "results.jsonl")]) == 0  # checks against an export too
    assert main(["suite", "verify", str(out)]) == 0
    (out / doc["cases"][0]["path"] / "input" / "capture.exr").write_bytes(b"changed")
    assert main(["suite", "verify", str(out)]) == 1
    capsys.readouterr()
    assert main(["score", str(out), "--results", str(full / "results.jsonl"), "--out", str(tmp_path / "s")]) == 2
    assert "without the truth to score against" in capsys.readouterr().err
    assert main(["suite", "export", str(built), "--out", str(out)]) == 2  # not empty: nothing overwritten
    assert (out / doc["cases"][0]["path"] / "input" / "capture.exr").read_bytes() == b"changed"
