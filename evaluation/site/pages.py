"""A report's Markdown as a page of the site, every link and image made to resolve there.

The Markdown is parsed by markdown-it-py (CommonMark with tables: what the
reports are written in). Each relative link or image is resolved against the
Markdown file, then:

- a Markdown file that is a page of the site: a link to that page;
- any other file inside one of the site's source folders: copied into the
  site (:class:`Place` says where) and linked there;
- anything else (a file outside the sources, a missing one, a folder): the
  link becomes its text, marked "not in the site", so no link is broken;
- absolute URLs and ``#fragment`` links are kept.
"""

from __future__ import annotations

import dataclasses
import os
import posixpath
from collections.abc import Callable
from pathlib import Path
from urllib.parse import unquote, urlsplit

from ...errors import UserError


@dataclasses.dataclass
class Place:
    """Where a source file goes in the site: ``site_path(src)`` a site-relative POSIX path or None (not in the
    site); ``page_of(src)`` the page a Markdown source is, or None. ``copies`` collects the files linked."""

    site_path: Callable[[Path], str | None]
    page_of: Callable[[Path], str | None]
    copies: dict[str, Path] = dataclasses.field(default_factory=dict)


def _parser():
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark").enable("table")


def title_of(text: str, default: str) -> str:
    """The first ``# `` heading of a Markdown text, or ``default``."""
    for line in text.splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    return default


def read_markdown(path: Path) -> str:
    """A Markdown file's text (UTF-8), or a one-line :class:`UserError` naming it."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text (expected a Markdown report)") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read it ({exc.strerror or exc})") from None


def page_html(source: Path, page: str, place: Place) -> str:
    """The HTML body of the Markdown file ``source`` shown as site page ``page`` (site-relative path).

    Links and images are rewritten as the module docstring says; the files they need are added to
    ``place.copies`` (site path -> source file).
    """
    md = _parser()
    tokens = md.parse(read_markdown(source))
    here = posixpath.dirname(page)
    for tok in tokens:
        opened: list[bool] = []  # per open link: whether it became a span
        for child in tok.children or ():
            if child.type == "link_open":
                opened.append(_relink(child, source, here, place))
            elif child.type == "link_close" and opened and opened.pop():
                child.tag = "span"
            elif child.type == "image":
                _reimage(child, source, here, place)
    return md.renderer.render(tokens, md.options, {})


def _target(url: str, source: Path, place: Place) -> tuple[str | None, str]:
    """The site path a relative ``url`` of ``source`` resolves to (None: not in the site) and its fragment."""
    parts = urlsplit(url)
    if parts.scheme or parts.netloc or not parts.path:
        return url, ""  # absolute, or a fragment of this page: kept as written
    file = Path(os.path.normpath(source.parent / unquote(parts.path)))
    fragment = f"#{parts.fragment}" if parts.fragment else ""
    if not file.is_file():
        return None, fragment
    page = place.page_of(file)
    if page is not None:
        return page, fragment
    dest = place.site_path(file)
    if dest is not None:
        place.copies[dest] = file
    return dest, fragment


def _relative(target: str, here: str) -> str:
    return posixpath.relpath(target, here or ".")


def _relink(tok, source: Path, here: str, place: Place) -> bool:
    """Point a link at the site; True when it became a span (its target is not in the site)."""
    href = str(tok.attrGet("href") or "")
    target, fragment = _target(href, source, place)
    if target == href:
        return False
    if target is None:
        tok.tag = "span"
        tok.attrs = {"class": "outside", "title": f"not in the site: {href}"}
        return True
    tok.attrSet("href", _relative(target, here) + fragment)
    return False


def _reimage(tok, source: Path, here: str, place: Place) -> None:
    src = str(tok.attrGet("src") or "")
    target, _ = _target(src, source, place)
    if target == src:
        return
    if target is None:
        tok.type, tok.tag, tok.children = "text", "", None
        tok.content = f"[image not in the site: {src}]"
        return
    tok.attrSet("src", _relative(target, here))
