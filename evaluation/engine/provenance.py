"""What made a committed report, and whether it still describes the code.

A report under ``reports/`` is only worth reading if the code that made it is
the code in the repository. :func:`record` writes ``provenance.json`` into a
results folder: the command to regenerate it, the commit that ran
(:func:`nearlight.evaluation.engine.environment.code_version`), the inputs (sweep and
scene files, by content hash) and the *code it depends on*: every nearlight
source file in the static import closure of the entry modules (imports inside
functions included, so lazily loaded stages count), by content hash.
:func:`stale` recomputes the hashes and names what changed;
``tests/test_reports_fresh.py`` fails on every committed report that is stale,
with the command that regenerates it.

Content hashes, not commits: a report stays valid across commits that do not
touch its code (docs, tests, another stage), and git history is not needed
(a release tarball checks the same way). The code is hashed as its tokens less
comments, docstrings and blank lines (:func:`code_tokens`), so tidying a
docstring or a comment leaves every report fresh while changing a constant or
a line of code makes the reports that import it stale; sweep and scene files
are hashed as bytes.

Regression baselines (``reports/smoke-baseline``) are held to the same rule:
a baseline older than the code it pins cannot tell a regression of today's
code from one that was already there. ``nearlight baseline``
(:mod:`nearlight.evaluation.views.baseline`) regenerates one, with its
verdict against the old one in writing, and ``nearlight compare`` warns when a
baseline is stale.
"""

from __future__ import annotations

import ast
import datetime as _dt
import hashlib
import io
import json
import os
import tokenize
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ...files.atomic import write_json
from ...files.digests import file_sha256
from ...files.outputs import check_file_out
from .environment import PACKAGE_ROOT, code_version

#: File name written into a results folder.
FILE = "provenance.json"


def _module_file(name: str) -> Path | None:
    """Source file of the nearlight module ``name`` (``nearlight.a.b``), or None when it is not one."""
    if name != "nearlight" and not name.startswith("nearlight."):
        return None
    parts = name.split(".")[1:]
    base = PACKAGE_ROOT.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_ROOT).with_suffix("")
    parts = [p for p in rel.parts if p != "__init__"]
    return ".".join(["nearlight", *parts])


def _imports(path: Path) -> set[str]:
    """Absolute names of the nearlight modules ``path`` imports anywhere (functions included)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)  # `from pkg import module`
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            found.add(node.args[0].value)
    return {n for n in found if n == "nearlight" or n.startswith("nearlight.")}


def dependencies(entry_modules: Iterable[str]) -> list[Path]:
    """The nearlight source files the entry modules depend on, sorted.

    Parameters
    ----------
    entry_modules : iterable of str
        Dotted names (``nearlight.evaluation.engine.run``).

    Returns
    -------
    list of Path
        The static import closure (parents' ``__init__.py`` included: importing
        ``a.b`` runs ``a/__init__.py``).
    """
    todo = list(entry_modules)
    seen: set[Path] = set()
    while todo:
        name = todo.pop()
        for i in range(1, name.count(".") + 2):  # the module and every package above it
            path = _module_file(".".join(name.split(".")[:i]))
            if path is not None and path not in seen:
                seen.add(path)
                todo.extend(_imports(path))
    return sorted(seen)


#: How a part's ``code`` entries are hashed (recorded as ``code_hash``; a record without it hashed raw bytes).
CODE_HASH = "python-tokens/1"


def code_tokens(source: str) -> list[str]:
    """The tokens of Python ``source`` that its behaviour depends on: no comments, no docstrings, no blank lines.

    Each token is ``"<type>:<text>"``; a string statement of its own (a
    docstring, or any string expression statement: neither does anything) is
    left out, as are comments and the line breaks of blank lines. Python
    3.12's tokenizer splits an f-string into parts that 3.11 keeps as one
    string: they are joined back to the source text, so the list is the same
    under either.
    """
    lines = source.splitlines(keepends=True)

    def text(start: tuple[int, int], end: tuple[int, int]) -> str:
        (r0, c0), (r1, c1) = start, end
        if r0 == r1:
            return lines[r0 - 1][c0:c1]
        return lines[r0 - 1][c0:] + "".join(lines[r0 : r1 - 1]) + lines[r1 - 1][:c1]

    out: list[str] = []
    statement_start = True  # the next token begins a statement
    pending: str | None = None  # a string at a statement's start: kept unless the statement ends with it
    depth = 0
    fstring_start = None
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        name = tokenize.tok_name[tok.type]
        if name == "FSTRING_START":
            depth += 1
            fstring_start = fstring_start or tok.start
            continue
        if depth:
            if name == "FSTRING_END":
                depth -= 1
                if not depth:
                    tok = tokenize.TokenInfo(tokenize.STRING, text(fstring_start, tok.end), fstring_start, tok.end, "")
                    name, fstring_start = "STRING", None
            if depth:
                continue
        if name in ("COMMENT", "NL", "ENCODING", "ENDMARKER"):
            continue
        if pending is not None:
            if name == "NEWLINE":  # the statement was the string alone: a docstring
                pending, statement_start = None, True
                continue
            out.append(pending)
            pending = None
        if name == "STRING" and statement_start:
            pending, statement_start = f"STRING:{tok.string}", False
            continue
        out.append(f"{name}:{tok.string if name not in ('NEWLINE', 'INDENT') else ''}")
        statement_start = name in ("NEWLINE", "INDENT", "DEDENT")
    if pending is not None:
        out.append(pending)
    return out


def code_hash(path: Path) -> str:
    """SHA-256 of a source file's :func:`code_tokens` (a Python file) or of its bytes (anything else), hex."""
    if path.suffix != ".py":
        return file_sha256(path)
    tokens = code_tokens(path.read_text(encoding="utf-8"))
    return hashlib.sha256("\n".join(tokens).encode("utf-8")).hexdigest()


def _rel(path: Path) -> str:
    try:
        return path.resolve().relative_to(PACKAGE_ROOT).as_posix()
    except ValueError:
        return str(path)


def record(
    folder: str | os.PathLike,
    *,
    command: str,
    entry_modules: Sequence[str],
    inputs: Sequence[str | os.PathLike] = (),
    part: str = "results",
) -> Path:
    """Write (or update one part of) ``folder/provenance.json``.

    Parameters
    ----------
    folder : path
        The results folder (a sweep's ``--out``, a reproduction's output).
    command : str
        The command that regenerates this part, as a user would type it.
    entry_modules : sequence of str
        Dotted module names the run entered; their import closure is hashed.
    inputs : sequence of path
        Files the run read (sweep file, scene files), hashed.
    part : str
        ``results`` (the run) or ``report`` (the view made from it): the two
        are made by different commands, each records its own.

    Returns
    -------
    Path
        The provenance file.
    """
    path = check_file_out(Path(folder) / FILE, "provenance")  # never a file nearlight did not write
    doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    if part == "results":  # a new run supersedes every view made from the old one
        doc = {}
    doc.setdefault("parts", {})[part] = {
        "command": command,
        "code_version": code_version(),
        "made": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "inputs": {_rel(Path(p)): file_sha256(Path(p)) for p in inputs},
        "code_hash": CODE_HASH,
        "code": {_rel(p): code_hash(p) for p in dependencies(entry_modules)},
    }
    return write_json(path, doc, what="the provenance record")


def stale(folder: str | os.PathLike) -> list[str]:
    """What changed since ``folder`` was made: one line per changed or missing part.

    Every ``provenance.json`` at or below ``folder`` is checked (a
    reproduction's report and each of its experiments' results folders).

    Returns
    -------
    list of str
        Empty when every recorded code and input file still has its hash;
        else lines such as ``"results: estimator/paper.py changed (made by
        0.1.0+g964de14; regenerate: nearlight sweep ...)"``.
    """
    folder = Path(folder)
    records = sorted(folder.rglob(FILE))
    if not records:
        return [f"{folder / FILE}: missing (no record of what made this folder)"]
    lines: list[str] = []
    for path in records:
        where = path.parent.relative_to(folder).as_posix()
        prefix = "" if where == "." else f"{where}: "
        doc = json.loads(path.read_text(encoding="utf-8"))
        parts: Mapping[str, Any] = doc.get("parts", {})
        for name, part in sorted(parts.items()):
            changed = []
            hashers = {"code": code_hash if part.get("code_hash") == CODE_HASH else file_sha256, "inputs": file_sha256}
            for kind, hasher in hashers.items():
                for rel, digest in part.get(kind, {}).items():
                    file = PACKAGE_ROOT / rel
                    if not file.is_file():
                        changed.append(f"{rel} missing")
                    elif hasher(file) != digest:
                        changed.append(f"{rel} changed")
            if changed:
                lines.append(f"{prefix}{name}: {', '.join(changed)} (made by {part.get('code_version')}; "
                             f"regenerate: {part.get('command')})")
    return lines
