"""Numbers the README and the docs quote from committed reports still say what those reports say.

A sentence such as "range noise carries most of the variance of the lamp
error (total index 0.88 ± 0.25)" is a copy of a number in a report under
``reports/``; when the report is regenerated and the number moves, the copy
drifts. Each row of :data:`QUOTES` names a doc, the phrase as the doc has it
with every quoted number written ``{}``, the report file that holds those
numbers and how to read each one. The golden values are the reports
themselves: the test reads each number from its report, formats it with the
rounding the doc uses, and asserts that the phrase so filled is in the doc
(whitespace and line breaks aside).

Only figures a committed report holds are here: benchmark output, the
paper's own numbers, run times and dates are not (run times and dates change
with every regeneration). Machine-readable report files (JSON, CSV, Parquet)
are preferred over their Markdown. To add a row, see ``reports/README.md``.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Cell:
    """The one row of a table (CSV, Parquet) whose columns equal ``where``, at ``column``."""

    where: dict
    column: str


@dataclass(frozen=True)
class Count:
    """How many rows of a table match ``where``; with ``distinct``, how many distinct values of that column."""

    where: dict = field(default_factory=dict)
    distinct: str | None = None


@dataclass(frozen=True)
class Quote:
    """One phrase of a doc and where its numbers come from.

    Attributes
    ----------
    doc : str
        The doc, relative to the repository root.
    phrase : str
        The phrase as the doc has it, each quoted number written ``{}``.
    report : str
        The report file holding the numbers, relative to ``reports/``.
    values : tuple
        How to read each ``{}``, in order: a tuple of keys (JSON), a
        :class:`Cell` or :class:`Count` (CSV, Parquet), or a regular
        expression with one group (Markdown).
    fmt : str
        The rounding the doc uses, a format applied to every value.
    """

    doc: str
    phrase: str
    report: str
    values: tuple
    fmt: str = "{}"


RANGE_NOISE = {"method": "full", "metric": "lamp_position_error_pct", "input": "range_noise"}

QUOTES = [
    Quote("README.md", "the object's shape (total index {} [{}, {}])", "global/sobol/gsa/indices.csv",
          tuple(Cell({**RANGE_NOISE, "input": "object"}, c) for c in ("ST", "ST_lo", "ST_hi")), "{:.2f}"),
    Quote("README.md", "and the viewing angle ({} [{}, {}]) lead", "global/sobol/gsa/indices.csv",
          tuple(Cell({**RANGE_NOISE, "input": "viewing_angle"}, c) for c in ("ST", "ST_lo", "ST_hi")), "{:.2f}"),
    Quote("README.md", "carries none ({} [{}, {}])", "global/sobol/gsa/indices.csv",
          tuple(Cell(RANGE_NOISE, c) for c in ("ST", "ST_lo", "ST_hi")), "{:.2f}"),
    Quote("README.md", "above the chance floor ({} [{}, {}], floor {})", "global/sobol/gsa/indices.csv",
          (*(Cell({**RANGE_NOISE, "input": "nuisances.camera.gamma"}, c) for c in ("ST", "ST_lo", "ST_hi")),
           Cell(RANGE_NOISE, "ST_floor")), "{:.2f}"),
    Quote("README.md", "clean and noisy, ideal and `bench` rig; {} captures)",
          "scores/core-v1/full/scorecard.json", (("cases",),)),
    Quote("docs/global-sensitivity.md", "`screening`: Morris, r = {} trajectories",
          "global/screening/gsa/gsa.md", (r"Design: `morris`, n = (\d+),",)),
    Quote("docs/global-sensitivity.md", "r = 20 trajectories ({} samples) for every built-in method",
          "global/screening/gsa/outputs.csv", (Count({"method": "full"}),)),
    Quote("docs/global-sensitivity.md", "named as such: {} runs,",
          "global/screening/gsa/outputs.csv", (Count(),)),
    Quote("docs/global-sensitivity.md", "{} distinct tasks on {} closed-form renders",
          "global/screening/results.parquet", (Count(), Count(distinct="render_key"))),
    Quote("docs/global-sensitivity.md", "`sobol`: Saltelli, N = {} (",
          "global/sobol/gsa/gsa.md", (r"Design: `sobol`, N = (\d+) \(",)),
    Quote("docs/global-sensitivity.md", "replicates of n = 1024: {} samples for `full`",
          "global/sobol/gsa/outputs.csv", (Count({"method": "full"}),)),
    Quote("docs/global-sensitivity.md", "the first replicate (seed 16) {} tasks on {} renders",
          "global/sobol/seed-16/results.parquet", (Count(), Count(distinct="render_key"))),
    Quote("docs/global-sensitivity.md", "the largest half-width of a total index of the lamp error in % is {} (the object's)",
          "global/sobol/gsa/indices.csv", (Cell({**RANGE_NOISE, "input": "object"}, "ST_conf"),), "{:.3f}"),
    Quote("docs/global-sensitivity.md", "the response curve's total index is {} [{}, {}] on the board and {} [{}, {}] on "
          "the sphere", "global/sobol/gsa/levels.csv",
          (*(Cell({**RANGE_NOISE, "input": "nuisances.camera.gamma", "level": "object=board"}, c)
             for c in ("ST", "ST_lo", "ST_hi")),
           *(Cell({**RANGE_NOISE, "input": "nuisances.camera.gamma", "level": "object=sphere"}, c)
             for c in ("ST", "ST_lo", "ST_hi"))), "{:.2f}"),
    Quote("docs/global-sensitivity.md", "the object's shape ({} [{}, {}])", "global/sobol/gsa/indices.csv",
          tuple(Cell({**RANGE_NOISE, "input": "object"}, c) for c in ("ST", "ST_lo", "ST_hi")), "{:.2f}"),
    Quote("docs/global-sensitivity.md", "floor is {} for the lamp error in %", "global/sobol/gsa/indices.csv",
          (Cell(RANGE_NOISE, "ST_floor"),), "{:.3f}"),
    Quote("docs/benchmark-suites.md", "(`reports/scores/paper-v1/`) `full` fails on {} of {} cases",
          "scores/paper-v1/full/scorecard.json", (("failed",), ("cases",))),
    Quote("docs/benchmark-suites.md", "`paper-init` on {} and",
          "scores/paper-v1/paper-init/scorecard.json", (("failed",),)),
    Quote("docs/benchmark-suites.md", "and `paper` on {} (3 where `t_max` cannot reach the lamp",
          "scores/paper-v1/paper/scorecard.json", (("failed",),)),
    # 8.97, the highlight's peak in noise deviations, is not in the report: only `full`'s error is checked
    Quote("docs/physics.md", "the realism study's board at gamma 1.5: 8.97, `full` {} % off",
          "realism/report/one_at_a_time.csv",
          (Cell({"axis": "set", "object": "board", "label": "gamma 1.5", "method": "full"}, "median"),), "{:.1f}"),
    Quote("docs/physics.md", "median lamp error on the bookend is {} % with the quantum and {} % without",
          "bench_seeds/bookend/report/one_at_a_time.csv",
          (Cell({"label": "bench"}, "median"), Cell({"label": "bench, range not quantised"}, "median")), "{:.2f}"),
    Quote("docs/physics.md", "on the torus {} % with and {} % without",
          "bench_seeds/curved/report/one_at_a_time.csv",
          (Cell({"label": "bench"}, "median"), Cell({"label": "bench, range not quantised"}, "median")), "{:.2f}"),
    Quote("docs/measurements/estimator-choices.md", "inside the ellipsoid {} at low noise and {} at high",
          "sensitivity/report/covariance.csv",
          (Cell({"axis": "noise", "value": "low", "method": "full"}, "inside_95"),
           Cell({"axis": "noise", "value": "high", "method": "full"}, "inside_95"))),
    Quote("README.md", "Of its {} cells the object's own highlight (`full`) wins {} ({} of the board's and {} of the "
          "sphere's)", "targets/report/winners.csv",
          (Count({"method": "full"}), Count({"method": "full", "winner": "full"}),
           Count({"method": "full", "winner": "full", "object": "board"}),
           Count({"method": "full", "winner": "full", "object": "sphere"}))),
    Quote("README.md", "an exact segmentation) {} of the bookend's {}; in the rest", "targets/report/winners.csv",
          (Count({"method": "mirror-silhouette", "winner": "mirror-silhouette", "object": "bookend"}),
           Count({"method": "mirror-silhouette", "object": "bookend"}))),
    Quote("README.md", "`mirror-spheres`' stated 95 % ellipsoid in {} of its captures, inside `full`'s in {} (",
          "targets/report/covariance.csv",
          (Cell({"axis": "all", "method": "mirror-spheres"}, "inside_95"),
           Cell({"axis": "all", "method": "full"}, "inside_95"))),
    Quote("README.md", "inside the card's (`lambertian-card`) in {}:", "targets/report/covariance.csv",
          (Cell({"axis": "all", "method": "lambertian-card"}, "inside_95"),)),
    Quote("docs/render-compare.md", "the {} captures of that study",
          "sensitivity/results.parquet", (Count({"method": "full"}),)),
]


def read_json(path: Path, keys: tuple):
    """The value at the key path ``keys`` of a JSON file."""
    value = json.loads(path.read_text())
    for key in keys:
        value = value[key]
    return value


def read_table(frame: pd.DataFrame, how: Cell | Count):
    """One number of a table: a :class:`Cell`'s value or a :class:`Count`."""
    rows = frame
    for column, value in how.where.items():
        rows = rows[rows[column] == value]
    if isinstance(how, Count):
        return int(rows[how.distinct].nunique()) if how.distinct else len(rows)
    assert len(rows) == 1, f"{how}: {len(rows)} rows match, not 1"
    value = rows[how.column].iloc[0]
    return value.item() if hasattr(value, "item") else value


def read_csv(path: Path, how: Cell | Count):
    """:func:`read_table` of a CSV file."""
    return read_table(pd.read_csv(path), how)


def read_parquet(path: Path, how: Cell | Count):
    """:func:`read_table` of a Parquet file."""
    return read_table(pd.read_parquet(path), how)


def read_markdown(path: Path, pattern: str):
    """The one group of the first match of ``pattern`` in a Markdown file (an int when it is digits)."""
    found = re.search(pattern, path.read_text())
    assert found, f"{path}: no match for {pattern!r}"
    return int(found.group(1)) if found.group(1).isdigit() else found.group(1)


READERS = {".json": read_json, ".csv": read_csv, ".parquet": read_parquet, ".md": read_markdown}


def flat(text: str) -> str:
    """``text`` with every run of whitespace one space, so a phrase may break across lines."""
    return " ".join(text.split())


def report_values(quote: Quote) -> list:
    """The numbers of ``quote`` as its report holds them now."""
    path = ROOT / "reports" / quote.report
    return [READERS[path.suffix](path, how) for how in quote.values]


@pytest.mark.parametrize("quote", QUOTES, ids=lambda q: f"{q.doc}: {q.phrase}")
def test_doc_quotes_its_report(quote):
    assert quote.phrase.count("{}") == len(quote.values), quote
    values = report_values(quote)
    expected = quote.phrase.format(*(quote.fmt.format(v) for v in values))
    doc = flat((ROOT / quote.doc).read_text())
    if flat(expected) in doc:
        return
    # what the doc says instead, where the phrase's words around the numbers match
    pattern = r"\S+?".join(re.escape(re.sub(r"\s+", " ", part)) for part in quote.phrase.split("{}"))
    found = re.search(pattern, doc)
    pytest.fail(
        f"{quote.doc}: the phrase {quote.phrase!r} should read {flat(expected)!r}: reports/{quote.report} "
        f"says {values} now; the doc has {found.group(0) if found else 'no such phrase'!r}. Fix the doc, or, "
        f"when the report is what is stale, regenerate it with its command in reports/README.md"
    )
