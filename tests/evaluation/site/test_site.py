"""``nearlight site``: the leaderboards hold every number of the scorecards, every link and image resolves.

Built from the committed reports of this checkout (``reports/``: the core-v1 and paper-v1 scorecards, every
report) and from a small folder made here (a self-reported scorecard, a report whose links leave the site).
Nothing renders.
"""

from __future__ import annotations

import json
import math
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


from nearlight.cli import main
from nearlight.evaluation.site.leaderboard import show, value_at

from .conftest import REPORTS


class _Links(HTMLParser):
    """Every href/src of a page, and every number link of a leaderboard (its text, pointer, scale, JSON)."""

    def __init__(self):
        super().__init__()
        self.refs: list[str] = []
        self.numbers: list[dict] = []
        self._open: dict | None = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("href", "src"):
            if a.get(key):
                self.refs.append(a[key])
        if tag == "a" and "data-pointer" in a:
            self._open = {"json": a["href"], "pointer": a["data-pointer"], "scale": float(a["data-scale"]), "text": ""}

    def handle_data(self, data):
        if self._open is not None:
            self._open["text"] += data

    def handle_endtag(self, tag):
        if tag == "a" and self._open is not None:
            self.numbers.append(self._open)
            self._open = None


def _parse(page: Path) -> _Links:
    p = _Links()
    p.feed(page.read_text(encoding="utf-8"))
    return p


def _broken_refs(site: Path) -> list[str]:
    broken = []
    for page in site.rglob("*.html"):
        for ref in _parse(page).refs:
            parts = urlsplit(ref)
            if parts.scheme or parts.netloc or not parts.path:
                continue  # a link out, or a fragment of the page
            if not (page.parent / unquote(parts.path)).is_file():
                broken.append(f"{page.relative_to(site)}: {ref}")
    return broken


def test_every_leaderboard_cell_is_its_scorecards_number(committed_site):
    boards = sorted(committed_site.glob("suite-*.html"))
    assert {b.name for b in boards} >= {"suite-core-v1.html", "suite-paper-v1.html"}
    checked = 0
    for board in boards:
        numbers = _parse(board).numbers
        assert numbers, board
        for n in numbers:
            card = json.loads((committed_site / n["json"]).read_text())
            assert n["text"] == show(value_at(card, n["pointer"], n["scale"])), (board.name, n)
            checked += 1
    # core-v1 has 4 methods x 12 category values; every row holds its ladder, medians, coverage, failures, time
    assert checked > 4 * 12 * 15


def test_every_link_and_image_of_the_site_resolves_and_the_reports_are_pages(committed_site):
    assert _broken_refs(committed_site) == []
    index = (committed_site / "index.html").read_text()
    for page in ("pages/reports/paper_reproduction/paper_reproduction.html", "pages/reports/sensitivity/report/summary.html",
                 "pages/reports/scores/core-v1/full/scorecard.html"):  # fmt: skip
        assert (committed_site / page).is_file() and f'href="{page}"' in index, page
    # the figures of a report are copied beside its page and shown there
    summary = (committed_site / "pages/reports/sensitivity/report/summary.html").read_text()
    assert "<img" in summary and (committed_site / "data/reports/sensitivity/report").is_dir()
    record = json.loads((committed_site / "site.json").read_text())
    assert record["format"] == "nearlight-site/1" and "index.html" in record["files"]


def _card(method: str, reported: dict | None = None) -> dict:
    group = {"category": "all", "value": "all", "n": 4, "failed": 1,
             "lamp_position_error_pct": {"recall": [0.25, 0.75], "median": 1.5, "median_ci95": [0.5, None]}}  # fmt: skip
    card = {"format": "nearlight-scorecard/1", "suite": "tiny-v1", "method": method, "cases": 4, "failed": 1,
            "thresholds": {"lamp_position_error_pct": [1.0, 5.0]}, "groups": [group], "runtime_s": {"median": 0.25},
            "code_version": ["0.4.0+gabc"], "machine": "test machine"}  # fmt: skip
    if reported:
        card["self_reported"] = reported
    return card


def test_a_self_reported_scorecard_is_marked_and_links_out_of_the_site_become_text(tmp_path, capsys):
    src = tmp_path / "results"
    for name, card in {"ours": _card("full"), "theirs": _card("their-method", {"file": "answers.jsonl",
                        "sha256": "0" * 64, "method_version": "2.1", "machine": "their laptop"})}.items():  # fmt: skip
        (src / name).mkdir(parents=True)
        (src / name / "scorecard.json").write_text(json.dumps(card))
    (src / "fig.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (src / "notes.md").write_text("# Notes\n\n![a figure](fig.png) [the docs](../../docs/x.md) [ours](ours/scorecard.json) "
                                  "[missing](nowhere.csv) [out](https://example.org) [here](#top)\n")  # fmt: skip
    site = tmp_path / "site"
    assert main(["site", str(src), "--out", str(site)]) == 0
    out, err = capsys.readouterr()
    assert out == f"{site / 'index.html'}\n" and err.startswith("site: 1 report pages, 2 scorecards on 1 leaderboards"), err
    board = (site / "suite-tiny-v1.html").read_text()
    assert "self-reported (answers.jsonl)" in board and ">2.1<" in board and ">nearlight<" in board
    # a null median bound is +∞ (more than half the resamples' cases are misses), as the scorecard means it
    assert 'data-pointer="/groups/0/lamp_position_error_pct/median_ci95/1" data-scale="1">∞<' in board
    notes = (site / "pages/results/notes.html").read_text()
    assert '<img src="../../data/results/fig.png"' in notes and (site / "data/results/fig.png").is_file()
    assert 'title="not in the site: ../../docs/x.md"' in notes and 'title="not in the site: nowhere.csv"' in notes
    assert 'href="../../data/results/ours/scorecard.json"' in notes and 'href="https://example.org"' in notes
    assert _broken_refs(site) == []

    # a rebuild replaces its own files; a file of the user's beside them stays, one where a page goes is refused
    (site / "mine.txt").write_text("keep")
    assert main(["site", str(src), "--out", str(site)]) == 0 and (site / "mine.txt").read_text() == "keep"
    (src / "more.md").write_text("# More\n")
    (site / "pages/results/more.html").write_text("<p>mine</p>")
    capsys.readouterr()
    assert main(["site", str(src), "--out", str(site)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "more.html: exists and nearlight did not write it" in err, err
    assert (site / "pages/results/more.html").read_text() == "<p>mine</p>"


def test_a_built_suite_shows_each_case_as_a_thumbnail_that_opens_its_contact_sheet(tmp_path, capsys):
    from nearlight.evaluation.suites.suite import load_suite, read_manifest

    doc = {"name": "thumbs-v1", "version": 1, "renderer": "analytic", "scene": {"width": 24, "height": 18},
           "axes": {"lamp_distance": [0.3, 0.5]}, "seeds": 1, "categories": ["lamp_distance"]}  # fmt: skip
    path = tmp_path / "suite.yaml"
    path.write_text(json.dumps(doc))
    path.write_text(json.dumps({**doc, "cases_hash": load_suite(path, check_pin=False).cases_hash}))
    built = tmp_path / "sources" / "thumbs"
    assert main(["suite", "build", str(path), "--out", str(built), "--quiet", "--no-cache"]) == 0
    site = tmp_path / "site"
    assert main(["site", str(tmp_path / "sources"), "--out", str(site)]) == 0
    page = site / "built" / "sources" / "thumbs" / "index.html"
    html = page.read_text()
    ids = [c["id"] for c in read_manifest(built)["cases"]]
    assert len(ids) == 2 and 'href="built/sources/thumbs/index.html"' in (site / "index.html").read_text()
    for case in ids:
        png = page.parent / f"{case}.png"
        assert png.read_bytes()[:4] == b"\x89PNG" and f'<a href="{case}.png"><img src="{case}.png"' in html
    assert "lamp_distance=0.3" in html and _broken_refs(site) == []
