"""The house: folder = import path, dependencies one way, one physics home (docs/architecture.md).

Walks the package's source files as text (``ast``), so it also sees imports
made inside functions, and imports every module to check that the name it is
imported by is its path.
"""

from __future__ import annotations

import ast
import importlib
import sys
import tomllib
from pathlib import Path

import pytest

import nearlight

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]

#: The pipeline, in the order data flows through it (docs/architecture.md).
STAGES = ("scenes", "generator", "capture", "estimator", "evaluation")
#: Beside the stages, imported by any of them and importing none.
SHARED = ("errors", "files", "physics")
#: What each part of the package may import (besides itself and the package's
#: ``__init__``, which holds ``__version__``). The generator writes the capture
#: format, the contract it shares with the estimator and real rigs: the one
#: import towards a later stage (checked below, so the table cannot grow others).
MAY_IMPORT: dict[str, set[str]] = {
    "errors": set(),
    "physics": {"errors"},
    "files": {"errors"},
    "scenes": set(),
    "generator": {"errors", "files", "physics", "scenes", "capture"},
    "capture": {"errors", "files", "physics"},
    "rig": {"errors", "files", "physics", "capture", "generator"},
    "estimator": {"errors", "files", "physics", "capture"},
    "evaluation": {"errors", "files", "physics", "scenes", "generator", "capture", "estimator"},
    # beside the estimator, outside its import path: the estimator reaches it by name only (estimator/api.py)
    "rendercompare": {"errors", "files", "physics", "generator", "capture", "estimator"},
    "cli": {"errors", "generator", "rig", "estimator", "evaluation"},
    "__main__": {"cli"},
    "__init__": {"errors"},
}


def source_modules() -> dict[str, Path]:
    """``{dotted name: file}`` for every module of the listed packages, from the folders."""
    out: dict[str, Path] = {}
    for package in PYPROJECT["packages"]:
        folder = ROOT.joinpath(*package.split(".")[1:])
        for path in sorted(folder.glob("*.py")):
            stem = [] if path.stem == "__init__" else [path.stem]
            out[".".join([package, *stem])] = path
    return out


def part_of(dotted: str) -> str:
    """The part of the package a module belongs to: ``nearlight.generator.render`` -> ``generator``."""
    parts = dotted.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


def imported_modules(name: str, path: Path) -> set[str]:
    """Dotted names of the nearlight modules or packages ``path`` imports, anywhere in it."""
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == "nearlight":
                out.add(target)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "nearlight")
    return out


MODULES = source_modules()


def test_packages_are_folders_under_the_root():
    # One mapping only: the repository root is the package `nearlight`.
    assert PYPROJECT["package-dir"] == {"nearlight": "."}
    for package in PYPROJECT["packages"]:
        assert (ROOT.joinpath(*package.split(".")[1:]) / "__init__.py").is_file(), package
    # the root's own modules are the package's face and its command: nothing else at the root ships
    assert sorted(p.name for p in ROOT.glob("*.py")) == ["__init__.py", "__main__.py", "cli.py", "errors.py"]
    # and every folder of the root that holds Python modules is a listed package or outside it on purpose
    listed = {ROOT.joinpath(*p.split(".")[1:]) for p in PYPROJECT["packages"]}
    for folder in ROOT.iterdir():
        if folder.is_dir() and not folder.name.startswith(".") and any(folder.glob("*.py")):
            assert folder in listed or folder.name in ("tests", "benchmarks"), folder


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n != "nearlight.__main__"))
def test_every_module_is_imported_by_its_path(name):
    module = importlib.import_module(name)
    installed = Path(nearlight.__file__).resolve().parent
    assert Path(module.__file__).resolve().relative_to(installed) == MODULES[name].relative_to(ROOT)


def test_no_module_imports_a_later_stage():
    for i, stage in enumerate(STAGES):
        later = set(STAGES[i + 1:]) & MAY_IMPORT[stage]
        assert later <= ({"capture"} if stage == "generator" else set()), (stage, later)
    for shared in SHARED:
        assert not MAY_IMPORT[shared] & set(STAGES), shared
    wrong = []
    for name, path in MODULES.items():
        part = part_of(name)
        for target in imported_modules(name, path):
            other = part_of(target)
            if target != "nearlight" and other != part and other not in MAY_IMPORT[part]:
                wrong.append(f"{path.relative_to(ROOT)} imports {target}")
    assert not wrong, wrong


def test_the_physics_home_imports_no_stage_and_only_numpy():
    physics = {n: p for n, p in MODULES.items() if part_of(n) == "physics"}
    assert {"nearlight.physics.reflectance", "nearlight.physics.polarization", "nearlight.physics.camera"} <= set(physics)
    for name, path in physics.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                tops = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level:
                tops = {(node.module or "").split(".")[0]}
            else:
                continue
            third_party = {t for t in tops if t not in sys.stdlib_module_names}
            assert third_party <= {"numpy"}, (name, third_party)
        assert {part_of(t) for t in imported_modules(name, path)} <= {"physics", "errors"}, name


def test_no_evaluation_module_name_begins_with_another_in_its_folder():
    # One job a module, named by its folder and its own name: `report.py` beside `report_luck.py` (or
    # `suite.py` beside `suite_cli.py`) is a folder the names are standing in for.
    evaluation = ROOT / "evaluation"
    folders = [evaluation, *(p for p in evaluation.rglob("*") if p.is_dir() and (p / "__init__.py").is_file())]
    clashes = []
    for folder in folders:
        names = sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")
        clashes += [f"{folder.relative_to(ROOT)}: {a}.py, {b}.py" for a in names for b in names
                    if a != b and b.startswith(a)]
    assert len(folders) > 1 and not clashes, clashes
