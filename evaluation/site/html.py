"""The site's HTML: Jinja2 templates (autoescaped), its style sheet and its table script.

Nothing is fetched at view time: the style and the script are the site's own
files, figures are PNG files copied beside the pages. Without JavaScript
every category's table is shown; with it, a menu picks one and a click on a
column header sorts by that column.
"""

from __future__ import annotations

import posixpath
from typing import Any

from .build import Site, suite_page
from .leaderboard import Cell

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1400px; padding: 0 1.2em 3em; color: #222; }
header { border-bottom: 1px solid #ccc; margin-bottom: 1em; }
header a { margin-right: 1em; }
table { border-collapse: collapse; margin: 0.6em 0 1.4em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 6px; vertical-align: top; }
th { background: #f3f3f3; cursor: pointer; position: sticky; top: 0; }
td a { color: inherit; text-decoration: none; border-bottom: 1px dotted #888; }
td.num, td.text { text-align: right; white-space: nowrap; }
td.text { text-align: left; }
.outside { color: #777; border-bottom: 1px dashed #bbb; }
img.broken { outline: 2px solid #c00; }
img { max-width: 100%; }
.note { color: #555; }
"""

JS = """
// nearlight site: show one category's table, sort a table by a clicked column (data-sort of its cells),
// and say so on the page when a figure does not load
document.addEventListener('DOMContentLoaded', function () {
  document.querySelectorAll('img').forEach(function (img) {
    function broken() { img.classList.add('broken'); img.alt = 'figure missing: ' + img.getAttribute('src'); }
    if (img.complete && img.naturalWidth === 0) { broken(); } else { img.addEventListener('error', broken); }
  });
  var pick = document.getElementById('group');
  function show() {
    document.querySelectorAll('section.group').forEach(function (s) {
      s.hidden = pick && s.dataset.group !== pick.value;
    });
  }
  if (pick) { pick.addEventListener('change', show); show(); }
  document.querySelectorAll('table.board th').forEach(function (th, col) {
    th.addEventListener('click', function () {
      var body = th.closest('table').tBodies[0], rows = Array.from(body.rows);
      var up = th.dataset.dir !== 'up'; th.dataset.dir = up ? 'up' : 'down';
      rows.sort(function (a, b) {
        var x = a.cells[th.cellIndex].dataset.sort, y = b.cells[th.cellIndex].dataset.sort;
        var nx = parseFloat(x), ny = parseFloat(y);
        var c = (isNaN(nx) || isNaN(ny)) ? String(x).localeCompare(String(y)) : nx - ny;
        return up ? c : -c;
      });
      rows.forEach(function (r) { body.appendChild(r); });
    });
  });
});
"""

LAYOUT = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{{ title }} · nearlight</title>
<link rel="stylesheet" href="{{ root }}style.css"><script src="{{ root }}site.js"></script></head>
<body><header><p><a href="{{ root }}index.html">nearlight results</a>{% for s in suites %}<a href="{{ root }}{{ s.page }}">{{ s.name }}</a>{% endfor %}</p></header>
{% block body %}{% endblock %}
<footer class="note"><p>Built by nearlight {{ version }}.</p></footer></body></html>
"""

INDEX = """{% extends "layout" %}{% block body %}
<h1>nearlight results</h1>
<h2>Leaderboards</h2>
{% if suites %}<ul>{% for s in suites %}<li><a href="{{ s.page }}">{{ s.name }}</a>: {{ s.methods|join(", ") }}</li>{% endfor %}</ul>
{% else %}<p class="note">No scorecard in the sources.</p>{% endif %}
<h2>Reports</h2>
{% for label, pages in reports %}<h3>{{ label }}</h3>
<table><thead><tr><th>report</th><th>file</th><th>made by</th></tr></thead><tbody>
{% for p in pages %}<tr><td><a href="{{ p.page }}">{{ p.title }}</a></td><td>{{ p.rel }}</td><td>{{ p.made }}</td></tr>
{% endfor %}</tbody></table>{% endfor %}
{% endblock %}"""

SUITE = """{% extends "layout" %}{% block body %}
<h1>Leaderboard: {{ name }}</h1>
<p class="note">One row per method and version; every number links to the scorecard JSON it comes from (hover: its
place in that file). Click a column to sort.</p>
<p><label>category <select id="group">{% for g in groups %}<option value="{{ g }}">{{ g }}</option>{% endfor %}</select></label></p>
{% for g in groups %}<section class="group" data-group="{{ g }}"><h2>{{ g }}</h2>
<table class="board" data-suite="{{ name }}"><thead><tr>{% for c in columns %}<th>{{ c }}</th>{% endfor %}<th>scorecard</th></tr></thead><tbody>
{% for b, row in rows[g] %}<tr data-json="{{ b.json }}">{% for c in columns %}{{ cell(row.cells.get(c), b) }}{% endfor %}
<td>{% if b.page %}<a href="{{ b.page }}">page</a>{% endif %} <a href="{{ b.json }}">json</a></td></tr>
{% endfor %}</tbody></table></section>{% endfor %}
{% endblock %}"""

PAGE = """{% extends "layout" %}{% block body %}
<p class="note">{{ rel }}{% if made %} · made by {{ made }}{% endif %}</p>
{{ body|safe }}
{% endblock %}"""


def _env():
    import jinja2

    return jinja2.Environment(loader=jinja2.DictLoader({"layout": LAYOUT, "index": INDEX, "suite": SUITE,
                                                        "page": PAGE}), autoescape=True)  # fmt: skip


def _cell(cell: Cell | None, board: Any, root: str = "") -> Any:
    """A ``<td>``: each number a link to the board's JSON, its pointer in ``title`` and ``data-pointer``."""
    from markupsafe import Markup, escape

    if cell is None:
        return Markup('<td data-sort=""></td>')
    if not cell.numbers:
        return Markup('<td class="text" data-sort="{}">{}</td>').format(cell.sort, cell.pattern)
    links = [Markup('<a href="{}" title="{}" data-pointer="{}" data-scale="{}">{}</a>').format(
        root + board.json, n.pointer, n.pointer, f"{n.scale:g}", n.text) for n in cell.numbers]
    return Markup('<td class="num" data-sort="{}">').format(cell.sort) + Markup(escape(cell.pattern).replace(
        "{}", "\x00")).replace("\x00", "{}").format(*links) + Markup("</td>")  # fmt: skip


def render(site: Site) -> dict[str, str]:
    """Every HTML page of ``site`` (site path -> text), plus its style sheet and script."""
    from ... import __version__

    env = _env()
    suites = site.suites()
    nav = [{"name": name, "page": suite_page(name), "methods": sorted({b.method for b in boards})}
           for name, boards in suites.items()]  # fmt: skip
    common = {"suites": nav, "version": __version__}
    out = {"style.css": CSS.lstrip(), "site.js": JS.lstrip()}
    reports: dict[str, list[dict[str, Any]]] = {}
    for p in sorted(site.pages, key=lambda p: p["page"]):
        rel = p["page"].split("/", 2)[2][: -len(".html")] + ".md"
        reports.setdefault(p["label"], []).append({**p, "rel": rel})
        root = "../" * p["page"].count("/")
        out[p["page"]] = env.get_template("page").render(**common, root=root, title=p["title"], rel=rel,
                                                          made=p["made"], body=p["body"])  # fmt: skip
    out["index.html"] = env.get_template("index").render(**common, root="", title="results",
                                                          reports=list(reports.items()))  # fmt: skip
    for name, boards in suites.items():
        groups = list(dict.fromkeys(r.group for b in boards for r in b.rows))
        columns = list(dict.fromkeys(c for b in boards for r in b.rows for c in r.cells))
        rows = {g: [(b, r) for b in boards for r in b.rows if r.group == g] for g in groups}
        out[suite_page(name)] = env.get_template("suite").render(**common, root="", title=name, name=name,
                                                                  groups=groups, columns=columns, rows=rows,
                                                                  cell=_cell)  # fmt: skip
    assert all(posixpath.normpath(k) == k for k in out)
    return out
