"""The package's licence and citation agree with pyproject.toml (issue 38, "a package people can cite").

CITATION.cff was validated against the Citation File Format 1.2.0 JSON schema (the one cffconvert 2.0.0
ships) when it was written; this test holds the facts that drift: its version and licence against
pyproject.toml's, and LICENSE's text against the licence pyproject.toml declares.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_license_file_is_the_declared_licence():
    project = _project()
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n")
    assert "Permission is hereby granted, free of charge" in text


def test_citation_names_this_version_and_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    project = _project()
    assert cff["cff-version"] == "1.2.0"
    assert str(cff["version"]) == project["version"]
    assert cff["license"] == project["license"]
    paper = cff["preferred-citation"]
    assert paper["title"].startswith("Estimating Light Position and Surface Reflectance from Specular Reflection")
    assert [a["family-names"] for a in paper["authors"]] == ["Hara", "Nishino", "Nakazawa", "Ikeuchi"]
