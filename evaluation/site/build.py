"""Build the static site: find the inputs, lay out the pages, write them (``nearlight site``).

Layout of ``SITE/``::

    index.html                       leaderboards, then every report page, by source folder
    suite-<suite>.html               a suite's leaderboard (a table per category value)
    history.html, history/<k>.png    each metric per commit of the committed scorecards and baselines, and per
                                     run of several results folders of one sweep (:mod:`.history`)
    built/<label>/<path>/index.html  a built suite's cases as thumbnails, each opening its contact sheet
                                     (``<id>.png``: ``nearlight show`` of the case's input capture); a built
                                     suite is a suite manifest beside a ``cases/`` folder (a manifest kept
                                     alone, as ``reports/references/`` keeps one, is not)
    pages/<label>/<path>.html        each Markdown report of source folder <label>, at its own path
    data/<label>/<path>              the scorecards and every file a page links or shows, copied
    style.css, site.js               the site's own style and table sorting (no file is fetched at view time)
    site.json                        what nearlight wrote here (``nearlight-site/1``): the output-place record

**Output place.** ``SITE`` must be absent, an empty folder, or a site that
nearlight wrote (its ``site.json``); a rebuild replaces only files that the
old ``site.json`` lists and refuses, before writing anything, when a file it
would write is there and not listed. Files it does not write are left alone.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import os
import posixpath
import re
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ...errors import UserError
from ...files.atomic import atomic_write, write_text
from ...files.outputs import check_folder
from ..engine.provenance import code_version
from ..suites.suite import FORMAT as SUITE_FORMAT
from .history import Series, committed_folders, folder_series, git_series, repository
from .leaderboard import Row, is_scorecard, rows, run_by, version
from .pages import Place, page_html, read_markdown, title_of

#: ``site.json``'s format.
SITE_FORMAT = "nearlight-site/1"
#: Folders the search for inputs does not enter: a sweep's result parts and render cache.
SKIP = {"parts", "renders", "__pycache__"}


@dataclasses.dataclass(frozen=True)
class Source:
    """One source folder of the site and the label its pages and data go under."""

    folder: Path
    label: str


@dataclasses.dataclass(frozen=True)
class Board:
    """One scorecard on a suite's leaderboard: its rows and where its JSON and its page are in the site."""

    suite: str
    method: str
    version: str
    run_by: str
    json: str
    page: str | None
    rows: list[Row]


def slug(name: str) -> str:
    """``name`` as a file name of the site: each run of characters other than letters, digits, ``.``, ``_``, ``-``
    becomes ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _sources(dirs: Sequence[str | os.PathLike]) -> list[Source]:
    out, labels = [], set()
    for d in dirs:
        folder = Path(d)
        if not folder.is_dir():
            raise UserError(f"{folder}: not a folder (expected a folder of reports, results or scorecards)")
        label = slug(folder.resolve().name) or "root"
        base, k = label, 2
        while label in labels:
            label, k = f"{base}-{k}", k + 1
        labels.add(label)
        out.append(Source(folder.resolve(), label))
    return out


def _walk(source: Source, exclude: Path) -> Iterable[Path]:
    """The files under a source folder, skipping result parts, render caches, hidden names and the site itself."""
    for root, dirs, files in os.walk(source.folder):
        here = Path(root)
        dirs[:] = sorted(d for d in dirs if d not in SKIP and not d.startswith(".") and (here / d).resolve() != exclude)
        yield from (here / f for f in sorted(files) if not f.startswith("."))


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not JSON ({exc.__class__.__name__}: {str(exc).splitlines()[0]})") from None


class Site:
    """The pages and files of one build, before anything is written."""

    def __init__(self, dirs: Sequence[str | os.PathLike], out: Path, *, history: bool = True):
        self.sources = _sources(dirs)
        self.out = out
        self.files: dict[str, str | bytes | Path] = {}  # site path -> text, bytes, or a source file to copy
        exclude = out.resolve()
        self.markdown: dict[Path, str] = {}  # source -> page
        self.cards: list[tuple[Path, str]] = []
        self.built: list[tuple[Path, Source]] = []
        where: dict[Path, Source] = {}
        for src in self.sources:
            for file in _walk(src, exclude):
                where[file] = src
                rel = file.relative_to(src.folder).as_posix()
                if file.suffix == ".md":
                    self.markdown[file] = f"pages/{src.label}/{rel[:-3]}.html"
                elif file.name == "scorecard.json":
                    self.cards.append((file, f"data/{src.label}/{rel}"))
                elif file.name == "manifest.json" and (file.parent / "cases").is_dir() and _is_suite_manifest(file):
                    self.built.append((file.parent, src))  # a manifest kept without its cases is no built suite
        self.history: list[Series] = self._history() if history else []
        if not self.markdown and not self.cards and not self.history and not self.built:
            raise UserError(f"{', '.join(str(s.folder) for s in self.sources)}: no scorecard.json and no Markdown report "
                            "under it (expected committed reports, results folders or score folders)")  # fmt: skip
        self.place = Place(site_path=lambda f: _data_path(f, self.sources), page_of=self.markdown.get)
        self.boards = self._boards()
        self.pages = self._pages()
        self.suites_built = [self._cases(folder, src) for folder, src in self.built]

    def _cases(self, folder: Path, src: Source) -> dict[str, Any]:
        """A built suite's page: each case's contact sheet (``nearlight show`` of its input capture) as a figure."""
        import tempfile

        from ...generator.show import contact_sheet
        from ..suites.suite import read_manifest

        manifest = read_manifest(folder)
        rel = folder.relative_to(src.folder).as_posix()
        page = posixpath.normpath(f"built/{src.label}/{rel}/index.html")
        cases = []
        with tempfile.TemporaryDirectory(prefix="nearlight-site-") as tmp:
            for case in manifest["cases"]:
                png = posixpath.join(posixpath.dirname(page), f"{case['id']}.png")
                out = contact_sheet(folder / case["path"] / "input", Path(tmp) / "sheet.png")
                self.files[png] = out.read_bytes()
                cases.append({"id": case["id"], "png": posixpath.basename(png),
                              "categories": ", ".join(f"{k}={v}" for k, v in case.get("categories", {}).items())})
        return {"name": str(manifest.get("name", folder.name)), "version": manifest.get("version", ""),
                "page": page, "folder": f"{src.label}/{rel}", "cases": cases}

    def _history(self) -> list[Series]:
        """The given results folders of one sweep, then the git history of the committed folders under the sources."""
        out = folder_series([s.folder for s in self.sources])
        repos: dict[Path, list[Path]] = {}
        for s in self.sources:
            repo = repository(s.folder)
            if repo is not None:
                repos.setdefault(repo, []).append(s.folder)
        for repo, folders in repos.items():
            out += git_series(repo, committed_folders(repo, folders))
        return out

    def _boards(self) -> list[Board]:
        boards = []
        for file, dest in self.cards:
            card = _read_json(file)
            if not is_scorecard(card):
                continue  # a file of that name that is not a scorecard: not ours to judge, not on a board
            try:
                got = rows(card)
            except (KeyError, IndexError, TypeError, ValueError) as exc:
                raise UserError(f"{file}: not a scorecard nearlight can read ({type(exc).__name__}: {exc}; expected "
                                "the groups, thresholds and recalls `nearlight score` writes)") from None  # fmt: skip
            self.files[dest] = file
            page = self.markdown.get(file.with_name("scorecard.md"))
            boards.append(Board(str(card.get("suite", "?")), str(card.get("method", "?")), version(card),
                                run_by(card), dest, page, got))  # fmt: skip
        return boards

    def _pages(self) -> list[dict[str, Any]]:
        out = []
        for file, page in self.markdown.items():
            text = read_markdown(file)
            out.append({"source": file, "page": page, "title": title_of(text, file.stem), "made": _made_by(file),
                        "label": next(s.label for s in self.sources if file.is_relative_to(s.folder)),
                        "body": page_html(file, page, self.place)})  # fmt: skip
        self.files.update(self.place.copies)
        return out

    def suites(self) -> dict[str, list[Board]]:
        """Boards by suite, in name order, each suite's methods in name order."""
        out: dict[str, list[Board]] = {}
        for b in sorted(self.boards, key=lambda b: (b.suite, b.method, b.version)):
            out.setdefault(b.suite, []).append(b)
        return out


def _is_suite_manifest(path: Path) -> bool:
    """Whether ``path`` claims to be a built suite's manifest (its reading checks the rest, one line if damaged)."""
    try:
        return json.loads(path.read_bytes().decode("utf-8")).get("format") == SUITE_FORMAT
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        return False


def _data_path(file: Path, sources: list[Source]) -> str | None:
    for s in sources:
        if file.resolve().is_relative_to(s.folder):
            return f"data/{s.label}/{file.resolve().relative_to(s.folder).as_posix()}"
    return None


def _made_by(file: Path) -> str:
    """The commit that made a report: the code_version of the nearest ``provenance.json`` at or above it."""
    for folder in (file.parent, *file.parents):
        prov = folder / "provenance.json"
        if prov.is_file():
            try:
                parts = json.loads(prov.read_text(encoding="utf-8")).get("parts", {})
                return ", ".join(sorted({str(p.get("code_version")) for p in parts.values() if p.get("code_version")}))
            except (ValueError, AttributeError):
                return ""
    return ""


def suite_page(suite: str) -> str:
    """The site path of a suite's leaderboard."""
    return f"suite-{slug(suite)}.html"


def check_site_out(out: str | os.PathLike, writes: Iterable[str]) -> set[str]:
    """Raise :class:`UserError` unless the site may be written into ``out`` (module docstring); nothing is written.

    Returns
    -------
    set of str
        The files the previous build there wrote (empty for a new place).
    """
    out = check_folder(out, what="site folder")
    if not out.exists() or not any(out.iterdir()):
        return set()
    record = out / "site.json"
    if not record.is_file():
        raise UserError(f"{out}: holds files nearlight did not write (expected an empty folder or a site "
                        "`nearlight site` wrote, with its site.json)")  # fmt: skip
    try:
        doc = json.loads(record.read_text(encoding="utf-8"))
        ours = set(doc["files"]) if doc.get("format") == SITE_FORMAT else None
    except (ValueError, KeyError, TypeError, AttributeError):
        ours = None
    if ours is None:
        raise UserError(f"{record}: not a site record nearlight wrote (expected format {SITE_FORMAT} with its files)")
    for rel in writes:
        path = out / rel
        if (path.exists() or path.is_symlink()) and rel not in ours:
            raise UserError(f"{path}: exists and nearlight did not write it (a rebuild replaces only the files "
                            "site.json lists)")  # fmt: skip
        if path.is_symlink() or (path.exists() and not path.is_file()):
            raise UserError(f"{path}: not a regular file (expected the site's own {Path(rel).name})")
    return ours


def write_site(site: Site, html: dict[str, str | bytes]) -> list[str]:
    """Write the pages ``html`` (site path -> text, or the bytes of a figure) and the copied files into
    ``site.out``, and its record.

    Returns
    -------
    list of str
        Every file written (site paths), sorted.
    """
    everything = {**site.files, **html}
    check_site_out(site.out, [*everything, "site.json"])
    for rel, what in sorted(everything.items()):
        dest = site.out / rel
        if isinstance(what, Path):
            dest.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(dest, lambda tmp, src=what: shutil.copyfile(src, tmp))
        elif isinstance(what, bytes):
            dest.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(dest, lambda tmp, data=what: Path(tmp).write_bytes(data))
        else:
            write_text(dest, what, what="the site")
    written = sorted([*everything, "site.json"])
    record = {"format": SITE_FORMAT, "code_version": code_version(), "made": dt.datetime.now(dt.UTC).isoformat(),
              "sources": [str(s.folder) for s in site.sources], "files": written}  # fmt: skip
    write_text(site.out / "site.json", json.dumps(record, indent=1) + "\n", what="the site")
    return written
