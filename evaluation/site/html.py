"""The site's HTML: Jinja2 templates (autoescaped), its style sheet and its table script.

Nothing is fetched at view time: the style and the script are the site's own
files, figures are PNG files copied beside the pages. Without JavaScript
every category's table is shown; with it, a menu picks one and a click on a
column header sorts by that column.
"""

from __future__ import annotations

import posixpath
from typing import Any

import io
import json

from .build import Site, suite_page
from .history import DRAWN, Series, history_json
from .leaderboard import Cell, Number, show

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1400px; padding: 0 1.2em 3em; color: #222; }
header { border-bottom: 1px solid #ccc; margin-bottom: 1em; }
header a { margin-right: 1em; }
table { border-collapse: collapse; margin: 0.6em 0 1.4em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 6px; vertical-align: top; }
th { background: #f3f3f3; cursor: pointer; position: sticky; top: 0; }
td a { color: inherit; text-decoration: none; border-bottom: 1px dotted #888; }
td.num, td.text { text-align: right; white-space: nowrap; }
td.worse { background: #fde2e2; }
td.worse::before { content: "▲ worse "; color: #b00; font-size: 11px; }
td.text { text-align: left; }
.outside { color: #777; border-bottom: 1px dashed #bbb; }
img.broken { outline: 2px solid #c00; }
img { max-width: 100%; }
.note { color: #555; }
.cases { display: flex; flex-wrap: wrap; gap: 10px; }
.cases figure { margin: 0; width: 240px; font-size: 12px; }
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
<body><header><p><a href="{{ root }}index.html">nearlight results</a>{% if history %}<a href="{{ root }}history.html">history</a>{% endif %}{% for s in suites %}<a href="{{ root }}{{ s.page }}">{{ s.name }}</a>{% endfor %}</p></header>
{% block body %}{% endblock %}
<footer class="note"><p>Built by nearlight {{ version }}.</p></footer></body></html>
"""

INDEX = """{% extends "layout" %}{% block body %}
<h1>nearlight results</h1>
<h2>Leaderboards</h2>
{% if suites %}<ul>{% for s in suites %}<li><a href="{{ s.page }}">{{ s.name }}</a>: {{ s.methods|join(", ") }}</li>{% endfor %}</ul>
{% else %}<p class="note">No scorecard in the sources.</p>{% endif %}
{% if history %}<h2>History</h2><p><a href="history.html">Each metric per commit of the committed scorecards and baselines</a>, with the commits where <code>compare</code> says a metric got worse marked.</p>{% endif %}
{% if built %}<h2>Built suites</h2><ul>{% for s in built %}<li><a href="{{ s.page }}">{{ s.name }} v{{ s.version }}</a>: {{ s.cases|length }} cases ({{ s.folder }})</li>{% endfor %}</ul>{% endif %}
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
{% for b, row in rows[g] %}<tr data-json="{{ b.json }}">{% for c in columns %}{{ cell(row.cells.get(c), b.json) }}{% endfor %}
<td>{% if b.page %}<a href="{{ b.page }}">page</a>{% endif %} <a href="{{ b.json }}">json</a></td></tr>
{% endfor %}</tbody></table></section>{% endfor %}
{% endblock %}"""

HISTORY = """{% extends "layout" %}{% block body %}
<h1>History</h1>
<p class="note">Each metric per run: per method, the median over the run's rows with its 95 % bootstrap interval (a
failed row counts as a miss), and the failed rows. A run is marked <b>▲ worse</b> on a method's metric where
<code>nearlight compare</code> of that run against the run before it fails that check. The runs of a committed
folder are the commits that changed its results, oldest first; every number links to <a href="data/history.json">history.json</a>.</p>
{% for s in series %}<section class="series"><h2>{{ s.name }}</h2>
<p class="note">{{ s.runs|length }} runs ({{ "commits" if s.origin == "git" else "results folders, in the order given" }});
{{ s.marked }} marked.</p>
<img src="{{ s.png }}" alt="{{ s.name }}: each metric per run">
{% for method, rows in s.tables %}<h3>{{ method }}</h3>
<table class="history" data-series="{{ s.index }}" data-method="{{ method }}"><thead><tr><th>run</th><th>date</th>{% for m in s.metrics %}<th>{{ m }}</th>{% endfor %}</tr></thead><tbody>
{% for run, cells in rows %}<tr data-run="{{ run.index }}"><td>{{ run.label }}</td><td>{{ run.when }}</td>{% for c in cells %}{{ c }}{% endfor %}</tr>
{% endfor %}</tbody></table>{% endfor %}</section>{% endfor %}
{% endblock %}"""

BUILT = """{% extends "layout" %}{% block body %}
<h1>Built suite: {{ s.name }} v{{ s.version }}</h1>
<p class="note">{{ s.folder }}: {{ s.cases|length }} cases; each shows what the method sees (its input capture);
click one for its contact sheet.</p>
<div class="cases">{% for c in s.cases %}<figure><a href="{{ c.png }}"><img src="{{ c.png }}" alt="case {{ c.id }}" width="240"></a>
<figcaption>{{ c.id }}{% if c.categories %}: {{ c.categories }}{% endif %}</figcaption></figure>{% endfor %}</div>
{% endblock %}"""

PAGE = """{% extends "layout" %}{% block body %}
<p class="note">{{ rel }}{% if made %} · made by {{ made }}{% endif %}</p>
{{ body|safe }}
{% endblock %}"""


def _env():
    import jinja2

    return jinja2.Environment(loader=jinja2.DictLoader({"layout": LAYOUT, "index": INDEX, "suite": SUITE,
                                                        "page": PAGE, "history": HISTORY, "built": BUILT}),
                              autoescape=True)  # fmt: skip


def _cell(cell: Cell | None, json: str, *, worse: bool = False) -> Any:
    """A ``<td>``: each number a link to the JSON file ``json`` (site path), its pointer in ``title`` and
    ``data-pointer``; ``worse`` marks it (a history run worse than the one before)."""
    from markupsafe import Markup, escape

    if cell is None:
        return Markup('<td data-sort=""></td>')
    if not cell.numbers:
        return Markup('<td class="text" data-sort="{}">{}</td>').format(cell.sort, cell.pattern)
    links = [Markup('<a href="{}" title="{}" data-pointer="{}" data-scale="{}">{}</a>').format(
        json, n.pointer, n.pointer, f"{n.scale:g}", n.text) for n in cell.numbers]
    kind = "num worse" if worse else "num"
    return Markup('<td class="{}" data-sort="{}">').format(kind, cell.sort) + Markup(escape(cell.pattern).replace(
        "{}", "\x00")).replace("\x00", "{}").format(*links) + Markup("</td>")  # fmt: skip


def _history_cell(point, k: int, j: int) -> Any:
    """A history ``<td>``: the value and its interval, each a link into ``data/history.json``; marked when worse."""
    base = f"/series/{k}/points/{j}"
    missing = float("nan") if point["metric"] == "failed" else float("inf")  # a null median is +∞: mostly misses
    values = [missing if v is None else v for v in (point["value"], point["lo"], point["hi"])]
    nums = [Number(v, show(v), f"{base}/{key}") for key, v in zip(("value", "lo", "hi"), values)]
    cell = Cell("{}" if point["metric"] == "failed" else "{} [{}, {}]", tuple(nums[:1] if point["metric"] == "failed"
                                                                              else nums), nums[0].value)  # fmt: skip
    return _cell(cell, "data/history.json", worse=bool(point["worse"]))


def history_figure(s: Series) -> bytes:
    """Each drawn metric per run (a panel per metric, a line per method, the interval as a bar, worse runs ringed
    red), as PNG bytes."""
    import numpy as np

    from ...files.figures import pyplot

    plt = pyplot()
    metrics = [m for m in DRAWN if m in set(s.points["metric"])]
    fig, axs = plt.subplots(len(metrics), 1, figsize=(max(6.0, 0.35 * len(s.runs) + 3), 2.3 * len(metrics)),
                            sharex=True, squeeze=False, constrained_layout=True)  # fmt: skip
    for ax, metric in zip(axs[:, 0], metrics):
        g = s.points[s.points["metric"] == metric]
        for method, m in g.groupby("method", sort=True):
            x, y = m["run"].to_numpy(), m["value"].to_numpy(dtype=float)
            lo, hi = m["lo"].to_numpy(dtype=float), m["hi"].to_numpy(dtype=float)
            ok = np.isfinite(lo) & np.isfinite(hi) & np.isfinite(y)
            line = ax.plot(x, np.where(np.isfinite(y), y, np.nan), marker="o", ms=3, lw=1, label=method)[0]
            ax.errorbar(x[ok], y[ok], yerr=[y[ok] - lo[ok], hi[ok] - y[ok]], fmt="none", lw=0.8,
                        color=line.get_color())  # fmt: skip
            bad = m["worse"].to_numpy(dtype=bool) & np.isfinite(y)
            ax.scatter(x[bad], y[bad], s=70, facecolors="none", edgecolors="red", linewidths=1.5, zorder=3)
        finite = g["value"].to_numpy(dtype=float)
        if metric != "failed" and (finite[np.isfinite(finite)] > 0).all() and np.isfinite(finite).any():
            ax.set_yscale("log")
        ax.set_ylabel(metric, fontsize=8)
    axs[0, 0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axs[-1, 0].set_xticks(range(len(s.runs)), [r.label for r in s.runs], rotation=90, fontsize=6)
    axs[0, 0].set_title("red rings: worse than the run before (nearlight compare)", fontsize=9)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _history_page(env: Any, common: dict[str, Any], site: Site, out: dict[str, Any]) -> None:
    doc = history_json(site.history)
    out["data/history.json"] = json.dumps(doc, indent=1) + "\n"
    view = []
    for k, (s, js) in enumerate(zip(site.history, doc["series"])):
        png = f"history/{k}.png"
        out[png] = history_figure(s)
        metrics = list(dict.fromkeys(p["metric"] for p in js["points"]))
        runs = [{"index": i, **r} for i, r in enumerate(js["runs"])]
        tables = []
        for method in sorted({p["method"] for p in js["points"]}):
            at = {(p["run"], p["metric"]): (j, p) for j, p in enumerate(js["points"]) if p["method"] == method}
            rows = [(run, [_history_cell(at[(run["index"], m)][1], k, at[(run["index"], m)][0])
                           if (run["index"], m) in at else "<td></td>" for m in metrics]) for run in runs]  # fmt: skip
            tables.append((method, rows))
        view.append({"index": k, "name": s.name, "origin": s.origin, "runs": s.runs, "png": png, "metrics": metrics,
                     "tables": tables, "marked": sum(p["worse"] for p in js["points"])})  # fmt: skip
    out["history.html"] = env.get_template("history").render(**common, root="", title="history", series=view)


def render(site: Site) -> dict[str, str | bytes]:
    """Every HTML page of ``site`` (site path -> text), its figures (bytes), its style sheet and script."""
    from ... import __version__

    env = _env()
    suites = site.suites()
    nav = [{"name": name, "page": suite_page(name), "methods": sorted({b.method for b in boards})}
           for name, boards in suites.items()]  # fmt: skip
    common = {"suites": nav, "version": __version__, "history": bool(site.history)}
    out = {"style.css": CSS.lstrip(), "site.js": JS.lstrip()}
    reports: dict[str, list[dict[str, Any]]] = {}
    for p in sorted(site.pages, key=lambda p: p["page"]):
        rel = p["page"].split("/", 2)[2][: -len(".html")] + ".md"
        reports.setdefault(p["label"], []).append({**p, "rel": rel})
        root = "../" * p["page"].count("/")
        out[p["page"]] = env.get_template("page").render(**common, root=root, title=p["title"], rel=rel,
                                                          made=p["made"], body=p["body"])  # fmt: skip
    out["index.html"] = env.get_template("index").render(**common, root="", title="results", built=site.suites_built,
                                                          reports=list(reports.items()))  # fmt: skip
    for name, boards in suites.items():
        groups = list(dict.fromkeys(r.group for b in boards for r in b.rows))
        columns = list(dict.fromkeys(c for b in boards for r in b.rows for c in r.cells))
        rows = {g: [(b, r) for b in boards for r in b.rows if r.group == g] for g in groups}
        out[suite_page(name)] = env.get_template("suite").render(**common, root="", title=name, name=name,
                                                                  groups=groups, columns=columns, rows=rows,
                                                                  cell=_cell)  # fmt: skip
    if site.history:
        _history_page(env, common, site, out)
    for s in site.suites_built:
        root = "../" * s["page"].count("/")
        out[s["page"]] = env.get_template("built").render(**common, root=root, title=s["name"], s=s)
    assert all(posixpath.normpath(k) == k for k in out)
    return out
