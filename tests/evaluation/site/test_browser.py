"""The site as a person sees it: Debian's Chromium, headless, opens the built site from the file system.

``--dump-dom`` gives the page after its script ran: the leaderboard's numbers are read from that DOM and held
to the scorecard JSON, only the ``all`` table shows until a category is picked, and no figure of any page failed
to load (the site's script marks such an image ``broken``). A screenshot of the core-v1 leaderboard and of the
index is saved in the test's folder (its path printed) to look at. Skipped, with its reason, where
``scripts/setup`` did not install Chromium (it does when the download takes under a minute).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import pytest

from nearlight.evaluation.site.leaderboard import show, value_at

from .test_site import _Links

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's Chromium is not installed (scripts/setup installs "
                                "it when its download takes under a minute)")  # fmt: skip


def _chromium(page: Path, *args: str) -> str:
    run = subprocess.run([CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                          "--virtual-time-budget=5000", *args, page.as_uri()],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def test_the_built_site_in_a_browser_shows_every_number_of_its_json_and_every_figure(committed_site, tmp_path, capsys):
    site = committed_site
    board = site / "suite-core-v1.html"
    dom = _chromium(board, "--dump-dom")
    links = _Links()
    links.feed(dom)
    assert len(links.numbers) > 4 * 12 * 15
    for n in links.numbers:
        assert n["text"] == show(value_at(json.loads((site / n["json"]).read_text()), n["pointer"], n["scale"])), n
    # the script ran: one category's table shows, the others wait for the menu
    assert dom.count('<section class="group" data-group="all">') == 1 and dom.count('hidden=""') == 11, dom[:500]
    broken = [p.relative_to(site).as_posix() for p in sorted(site.rglob("*.html"))
              if 'class="broken"' in _chromium(p, "--dump-dom")]  # fmt: skip
    assert broken == [], broken
    for name, page in (("leaderboard", board), ("index", site / "index.html")):
        shot = tmp_path / f"{name}.png"
        _chromium(page, f"--screenshot={shot}", "--window-size=1400,900")
        assert shot.read_bytes()[:4] == b"\x89PNG"
        with capsys.disabled():
            print(f"\nsite screenshot: {shot}")
