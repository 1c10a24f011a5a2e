"""The site of this checkout's committed reports, built once for every site test (with the git history: ~30 s)."""

from __future__ import annotations

from pathlib import Path

import pytest

from nearlight.cli import main

REPORTS = Path(__file__).resolve().parents[3] / "reports"


@pytest.fixture(scope="session")
def committed_site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site") / "site"
    assert main(["site", str(REPORTS), "--out", str(site)]) == 0
    return site
