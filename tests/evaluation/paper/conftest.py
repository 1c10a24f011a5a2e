"""One ``nearlight reproduce --quick`` run for every test of this folder that needs one."""

from __future__ import annotations

import json

import pytest

from nearlight.cli import main


@pytest.fixture(scope="session")
def quick_report(tmp_path_factory):
    """``(folder, document)`` of a quick reproduction rendered on this machine."""
    out = tmp_path_factory.mktemp("reproduce")
    assert main(["reproduce", "--quick", "--quiet", "--out", str(out)]) == 0
    return out, json.loads((out / "paper_reproduction.json").read_text())
