"""Runs kept from other CPUs (``reports/references/``) against this machine's, within the stated classes.

The quick test renders on whatever machine runs the suite, so every new
development machine checks itself against every kept CPU. The full-profile
tests read committed files only: the committed report (made on the machine
that last regenerated it) against the references of other CPUs, the real
flips between two of them, and a planted shift that must fail.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from nearlight.evaluation.paper import references as refs
from nearlight.evaluation.paper.check import check, machine

ROOT = Path(__file__).resolve().parents[3]
COMMITTED = ROOT / "reports" / "paper_reproduction" / "paper_reproduction.json"


def _kept(profile):
    return [p.parent.name for p in sorted(refs.FOLDER.glob(f"*/{refs.RECORD}"))
            if json.loads(p.read_text())["profile"] == profile]


def _reference(name, profile):
    found = [r for r in refs.references(profile) if r[0] == name]
    assert found, f"reference {name} not found for profile {profile}"
    return found[0]


def _agree(new, name, profile):
    _, ref, live, retired = _reference(name, profile)
    if not live:
        pytest.skip(f"reference {name}: every table retired (their code changed since it was kept: "
                    f"{', '.join(retired)}); delete it")
    lines, misses = check(new, ref, tables=live)
    assert misses == 0, (f"this run ({machine(new)}) against reference {name} ({machine(ref)}):\n"
                         + "\n".join(lines))
    return lines


def test_there_are_references_from_other_cpus():
    flags = {tuple(json.loads((refs.FOLDER / n / refs.RECORD).read_text())["cpu_flags"]) for n in _kept("full")}
    assert _kept("quick") and len(flags) >= 2


@pytest.mark.parametrize("name", _kept("quick"))
def test_this_machine_agrees_with_a_kept_quick_reference(quick_report, name):
    _, doc = quick_report
    _agree(doc, name, "quick")


@pytest.mark.parametrize("name", _kept("full"))
def test_the_committed_report_agrees_with_a_kept_full_reference(name):
    _agree(json.loads(COMMITTED.read_text()), name, "full")


def _doc(name):
    return json.loads((refs.FOLDER / name / "paper_reproduction.json").read_text())


def test_real_flips_between_two_cpus_pass_as_brightest_pixel_and_fail_as_continuous():
    # The Xeon (AVX-512) and the AVX2 EPYC, both host targets: their printed `paper-init` rows flipped
    # (54.3 -> 55.2 % median). The brightest-pixel class must accept that; treated as continuous
    # (as if both had rendered the same bits) the same two documents must not agree.
    xeon, avx2 = _doc("xeon-avx512-host-b06c2c8"), _doc("epyc-avx2-host-def7095")
    lines, misses = check(xeon, avx2, tables=["first_stage"])
    assert misses == 0, lines
    assert "240 brightest-pixel row numbers not compared value by value (11 moved" in lines[1], lines[1]
    same = copy.deepcopy(avx2)
    same["environment"] = xeon["environment"]
    _, misses = check(xeon, same, tables=["first_stage"])
    assert misses >= 9, misses


@pytest.mark.parametrize("quantile", ["median", "p10", "p90"])
@pytest.mark.parametrize("shift", [5.0, -5.0])
def test_a_planted_5_point_shift_of_a_printed_quantile_fails(quantile, shift):
    doc = json.loads(COMMITTED.read_text())
    doc["experiments"]["first_stage"]["distributions"]["paper-init"]["all"][quantile] += shift
    _, ref, live, _ = _reference("epyc-avx2-host-def7095", "full")
    assert "first_stage" in live
    lines, misses = check(doc, ref, tables=["first_stage"])
    assert misses == 1, lines
    failed = lines[-1]
    assert failed.startswith(f"  first_stage: paper-init: all: {quantile}: ") and "brightest-pixel" in failed
    assert "AMD EPYC (sse4_2 avx avx2 fma; target host)" in lines[0]  # both machines named


def test_a_table_whose_code_changed_is_retired(tmp_path, quick_report):
    out, _ = quick_report
    refs.keep(out, "here", ["board", "first_stage"], note="test", folder=tmp_path)
    (name, _, live, retired), = refs.references("quick", folder=tmp_path)
    assert (name, live, retired) == ("here", ["board", "first_stage"], [])
    record = json.loads((tmp_path / "here" / refs.RECORD).read_text())
    record["tables"]["board"] = "0" * 64  # as if board's code had changed since
    (tmp_path / "here" / refs.RECORD).write_text(json.dumps(record))
    (_, _, live, retired), = refs.references("quick", folder=tmp_path)
    assert (live, retired) == (["first_stage"], ["board"])
    assert refs.references("full", folder=tmp_path) == []


@pytest.mark.parametrize("args, says", [
    (["reproduction", "{tmp}/none", "x", "--tables", "board", "--note", "n"], "cannot read a reproduction document"),
    (["reproduction", "{run}", "x", "--tables", "nope", "--note", "n"], "--tables: nope not in"),
    (["reproduction", "{run}", "taken", "--tables", "board", "--note", "n"], "a reference of that name exists"),
])
def test_keep_reference_refuses_bad_input_in_one_line(tmp_path, quick_report, args, says, monkeypatch, capsys):
    out, _ = quick_report
    monkeypatch.setattr(refs, "FOLDER", tmp_path)
    (tmp_path / "taken").mkdir()
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import keep_reference
    finally:
        sys.path.pop(0)
    original = refs.keep
    monkeypatch.setattr(refs, "keep", lambda *a, **k: original(*a, **{**k, "folder": tmp_path}))
    argv = [a.format(tmp=tmp_path, run=out) for a in args]
    assert keep_reference.main(argv) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1, err


def test_keep_reference_script_runs(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "keep_reference.py"), "reproduction", str(tmp_path), "x",
                           "--tables", "board", "--note", "n"], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "cannot read" in done.stderr


def _run(folder, experiments, *, cpu="AMD EPYC", version="0.3.0+gaaaaaaa"):
    folder.mkdir(parents=True)
    doc = {"code_version": version, "profile": {"name": "full"}, "experiments": experiments,
           "environment": {"cpu": cpu, "cpu_flags": ["avx2"], "jit_target": "x86-64-v3"}}
    (folder / "paper_reproduction.json").write_text(json.dumps(doc))
    return folder


def test_a_change_that_left_a_table_as_it_was_carries_it_and_one_that_moved_it_does_not(tmp_path):
    """refs.carry: a retired table is carried only when this machine's runs before and after agree on it to the
    last bit (run times and code versions aside) and the reference recorded the fingerprint of the code before."""
    now = refs.fingerprints(quick=False)
    before = {"board": "old-board", "bookend": "old-bookend", "first_stage": "older"}
    kept = tmp_path / "refs" / "elsewhere"
    kept.mkdir(parents=True)
    (kept / "paper_reproduction.json").write_text("{}")
    record = {"profile": "full", "tables": dict(before), "note": "test"}
    (kept / refs.RECORD).write_text(json.dumps(record))
    table = {"rows": [{"lamp_position_error_pct": 1.5, "runtime_s": 0.3}], "code_versions": ["a"]}
    moved = {"rows": [{"lamp_position_error_pct": 1.6, "runtime_s": 0.3}]}
    old = _run(tmp_path / "old", {"board": table, "bookend": table, "first_stage": table})
    new = _run(tmp_path / "new", {"board": {**table, "rows": [{"lamp_position_error_pct": 1.5, "runtime_s": 9.0}],
                                            "code_versions": ["b"]},
                                  "bookend": moved, "first_stage": table}, version="0.3.0+gbbbbbbb")
    fp = {"full": {"board": "old-board", "bookend": "old-bookend", "first_stage": "old-first-stage"}}
    assert refs.carry(old, new, fp, note="test change", folder=tmp_path / "refs") == ["elsewhere/board"]
    after = json.loads((kept / refs.RECORD).read_text())
    assert after["tables"] == {"board": now["board"], "bookend": "old-bookend", "first_stage": "older"}
    assert after["carried"] == [{"table": "board", "from": "old-board", "to": now["board"], "before": "0.3.0+gaaaaaaa",
                                 "after": "0.3.0+gbbbbbbb", "note": "test change"}]
    (_, _, live, retired), = refs.references("full", folder=tmp_path / "refs")
    assert live == ["board"] and retired == ["bookend", "first_stage"]
    # two machines' runs are no evidence of one change
    other = _run(tmp_path / "xeon", {"board": table}, cpu="Intel Xeon")
    with pytest.raises(refs.UserError, match="not one machine's runs \\(cpu differ\\)"):
        refs.carry(old, other, fp, note="x", folder=tmp_path / "refs")


def test_carry_refuses_a_folder_without_a_reproduction_in_one_line(tmp_path):
    fp = tmp_path / "fp.json"
    fp.write_text(json.dumps({"full": {}}))
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "keep_reference.py"), "carry", str(tmp_path / "none"),
                          str(tmp_path / "none2"), str(fp), "--note", "x"], capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.count("\n") == 1 and "cannot read a reproduction document" in run.stderr
