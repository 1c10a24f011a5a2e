"""``nearlight reproduce --quick``: the README's main job, end to end on real renders."""

from __future__ import annotations

import json

import pytest

from nearlight.cli import main
from nearlight.evaluation.reproduce import ALL_METHODS, EXPERIMENTS, NEAR_METHODS, finite_numbers


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    assert main(["reproduce", "--quick", "--no-progress", "--out", str(out)]) == 0
    return out, json.loads((out / "paper_reproduction.json").read_text())


def test_report_json_and_figures_exist(quick_report, capsys):
    out, doc = quick_report
    md = (out / "paper_reproduction.md").read_text()
    assert set(doc["experiments"]) == set(EXPERIMENTS)
    for name, ex in doc["experiments"].items():
        assert ex["figures"], name
        for fig in ex["figures"]:
            assert (out / fig).stat().st_size > 10_000, fig  # a real picture, not an empty canvas
            assert f"]({fig})" in md, fig


def test_every_method_and_scene_has_finite_numbers(quick_report):
    _, doc = quick_report
    assert finite_numbers(doc)
    for name in ("board", "bookend", "curved"):
        methods = doc["experiments"][name]["methods"]
        assert list(methods) == list(NEAR_METHODS)
        for m, row in methods.items():
            assert len(row["lamp_position"]) == 3 and row["lamp_position_error_m"] is not None, (name, m)
    rows = doc["experiments"]["near_vs_distant"]["rows"]
    assert {r["method"] for r in rows} == set(ALL_METHODS)


def test_full_method_is_within_one_percent_on_the_paper_board(quick_report):
    # Issue 5: on the §4.1 board `full` is within 1 % of the lamp distance. The quick
    # profile (160x120, 4 angles, noise-free) fits a Torrance–Sparrow lobe to a Ward
    # surface: the residual model mismatch, not noise, sets the error (0.3 % measured).
    _, doc = quick_report
    assert doc["experiments"]["board"]["methods"]["full"]["lamp_position_error_pct"] < 1.0


def test_near_field_beats_distant_when_the_lamp_is_near(quick_report):
    # The paper's motivation: with the lamp 0.15 m from the board the distant-light
    # baseline is off by more than the lamp's distance, `full` by well under 1 %.
    _, doc = quick_report
    rows = doc["experiments"]["near_vs_distant"]["rows"]
    nearest = min(r["distance_m"] for r in rows)
    by = {r["method"]: r for r in rows if r["distance_m"] == nearest}
    assert by["distant"]["lamp_position_error_pct"] > 50.0
    assert by["full"]["lamp_position_error_pct"] < 1.0


def test_unwritable_out_is_a_one_line_error(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    assert main(["reproduce", "--quick", "--no-progress", "--out", str(tmp_path / "file" / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nearlight: error:") and "\n" not in err


def test_check_against_another_run(quick_report):
    from nearlight.evaluation.reproduce_check import TOLERANCES, check

    _, doc = quick_report
    lines, misses = check(doc, doc)
    assert misses == 0 and [line.split(":")[0] for line in lines] == list(EXPERIMENTS)
    moved = json.loads(json.dumps(doc))
    row = moved["experiments"]["board"]["methods"]["full"]
    row["lamp_position_error_pct"] += 0.5 * TOLERANCES["lamp_position_error_pct"]  # within: agrees
    assert check(moved, doc)[1] == 0
    row["lamp_position_error_pct"] += 5 * TOLERANCES["lamp_position_error_pct"]
    del moved["experiments"]["near_vs_distant"]["rows"][0]
    lines, misses = check(moved, doc)
    assert misses == 1 + len(TOLERANCES), lines
    assert any("board: full: lamp_position_error_pct" in line for line in lines)


def test_against_a_reference_of_another_profile_is_refused_before_work(quick_report, tmp_path, capsys):
    _, doc = quick_report
    ref = tmp_path / "ref"
    ref.mkdir()
    (ref / "paper_reproduction.json").write_text(json.dumps({**doc, "profile": {**doc["profile"], "name": "full"}}))
    out = tmp_path / "out"
    assert main(["reproduce", "--quick", "--no-progress", "--out", str(out), "--against", str(ref)]) == 2
    err = capsys.readouterr().err.strip()
    assert "profile 'full', this run is 'quick'" in err and "\n" not in err and not out.exists()
