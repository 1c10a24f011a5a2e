"""The house: folder = import path, dependencies one way, one physics home (docs/architecture.md).

Walks the package's source files as text (``ast``), so it also sees imports
made inside functions (no module may import a later stage, and no modules may
import each other), and imports every module to check that the name it is
imported by is its path.
"""

from __future__ import annotations

import ast
import importlib
import sys
import tomllib
from collections.abc import Mapping
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


def import_statements(name: str, path: Path) -> list[tuple[str, list[str] | None]]:
    """Every import in ``path``, anywhere in it: ``(module, names)`` of ``from module import names`` (relative
    imports resolved), ``(module, None)`` of ``import module``."""
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    out: list[tuple[str, list[str] | None]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.append((target, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            out.extend((a.name, None) for a in node.names)
    return out


def imported_modules(name: str, path: Path) -> set[str]:
    """Dotted names of the nearlight modules or packages ``path`` imports, anywhere in it."""
    return {module for module, _ in import_statements(name, path) if module.split(".")[0] == "nearlight"}


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
            assert folder in listed or folder.name in ("tests", "benchmarks", "scripts"), folder  # scripts: maintainers' tools


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


def module_imports(name: str, path: Path, modules: Mapping[str, Path]) -> set[str]:
    """The modules of ``modules`` that ``path`` imports, anywhere in it (inside functions too).

    ``from PKG import x`` is module ``PKG.x`` where there is one, else the
    package ``PKG`` whose names it takes; a package's ``__init__`` that its own
    module ran on the way (``import PKG.x``) is not counted.
    """
    out = set()
    for module, names in import_statements(name, path):
        if names is None:
            out.update({module} & set(modules))
            continue
        submodules = {f"{module}.{n}" for n in names} & set(modules)
        out |= submodules
        if len(submodules) < len(names) and module in modules:
            out.add(module)
    return out - {name}


def import_cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The import loops of ``graph`` (module -> the modules it imports): each strongly connected set of two or
    more modules, sorted (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    loops: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                loops.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(loops)


def test_no_module_import_loop_anywhere_in_the_package():
    # A loop hidden by an import inside a function is a loop all the same: the two modules cannot be read,
    # tested or moved one without the other.
    graph = {name: module_imports(name, path, MODULES) for name, path in MODULES.items()}
    loops = import_cycles(graph)
    assert loops == [], "modules that import each other"


def test_the_loop_check_sees_imports_made_inside_functions(tmp_path):
    (tmp_path / "a.py").write_text("from .b import g\n\ndef f():\n    return g()\n")
    (tmp_path / "b.py").write_text("def g():\n    from .a import f\n    return f\n")
    (tmp_path / "c.py").write_text("from . import a\n")
    modules = {f"pkg.{m}": tmp_path / f"{m}.py" for m in "abc"}
    graph = {name: module_imports(name, path, modules) for name, path in modules.items()}
    assert graph == {"pkg.a": {"pkg.b"}, "pkg.b": {"pkg.a"}, "pkg.c": {"pkg.a"}}
    assert import_cycles(graph) == [["pkg.a", "pkg.b"]]


#: Longest module of the estimator, lines: a room of one job, which a newcomer reads whole.
MAX_ESTIMATOR_LINES = 600


def test_no_estimator_module_is_over_600_lines():
    lengths = {str(path.relative_to(ROOT)): len(path.read_text().splitlines())
               for name, path in MODULES.items() if part_of(name) == "estimator"}
    assert len(lengths) > 10, lengths
    assert {p: n for p, n in lengths.items() if n > MAX_ESTIMATOR_LINES} == {}


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
