"""A suite's leaderboard from its scorecards: one row per method, version and category.

Every number a row shows keeps the JSON pointer (RFC 6901) of the value it
came from in its ``scorecard.json``, so the page links each number to its
source and a test can hold every cell to its JSON
(``tests/evaluation/site/test_site.py``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from ..suites.ladders import LADDERS

#: ``scorecard.json``'s format prefix (:mod:`nearlight.evaluation.suites.scorecard`).
SCORECARD_FORMAT = "nearlight-scorecard/"


@dataclasses.dataclass(frozen=True)
class Number:
    """One number of a cell: its value, as shown, and where it is in the scorecard.

    Attributes
    ----------
    value : float
        The JSON's value times ``scale``.
    text : str
        As the page shows it (:func:`show`).
    pointer : str
        RFC 6901 pointer into the scorecard JSON, e.g. ``/groups/0/lamp_position_error_pct/median``.
    scale : float
        What the JSON's value is multiplied by to be shown (100 for a fraction shown in %).
    """

    value: float
    text: str
    pointer: str
    scale: float = 1.0


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell: its numbers (none for a label), a pattern joining them, and the value the table sorts by.

    ``pattern`` has one ``{}`` per number (``"{} [{}, {}]"`` for a median with its interval); a label cell has
    no numbers and ``pattern`` is its text.
    """

    pattern: str
    numbers: tuple[Number, ...] = ()
    sort: float | str = ""


@dataclasses.dataclass(frozen=True)
class Row:
    """One row: a method's scorecard on one category value of the suite.

    Attributes
    ----------
    group : str
        ``"<category>=<value>"`` (``"all"`` for the whole suite).
    cells : dict
        Column header -> :class:`Cell`, in column order.
    """

    group: str
    cells: dict[str, Cell]


def show(x: float) -> str:
    """A number as a table shows it: 3 significant digits, ``∞`` for +∞, ``n/a`` for a missing one."""
    if math.isinf(x) and x > 0:
        return "∞"
    return "n/a" if not math.isfinite(x) else f"{x:.3g}"


def value_at(card: Mapping[str, Any], pointer: str, scale: float = 1.0) -> float:
    """The number at ``pointer`` in a scorecard, times ``scale``. A JSON null is +∞ where the scorecard means it
    so (a median or its interval's bound where more than half the cases are misses:
    :func:`nearlight.evaluation.suites.scorecard.median_ci`), NaN elsewhere (not given)."""
    value = resolve(card, pointer)
    if value is None:
        return math.inf if "/median" in pointer else math.nan
    return float(value) * scale


def _number(card: Mapping[str, Any], pointer: str, scale: float = 1.0) -> Number:
    x = value_at(card, pointer, scale)
    return Number(x, show(x), pointer, scale)


def resolve(doc: Any, pointer: str) -> Any:
    """The value at an RFC 6901 ``pointer`` in ``doc`` (``KeyError``/``IndexError`` when it is not there)."""
    for part in pointer.split("/")[1:]:
        part = part.replace("~1", "/").replace("~0", "~")
        doc = doc[int(part)] if isinstance(doc, list) else doc[part]
    return doc


def is_scorecard(doc: Any) -> bool:
    """Whether ``doc`` is a scorecard (a JSON object of the scorecard format with ``groups``)."""
    return isinstance(doc, dict) and str(doc.get("format", "")).startswith(SCORECARD_FORMAT) and isinstance(
        doc.get("groups"), list)


def version(card: Mapping[str, Any]) -> str:
    """The version a row names: the self-reported file's method version, else the code versions that ran it."""
    rep = card.get("self_reported")
    if rep:
        return str(rep.get("method_version", "?"))
    return ", ".join(map(str, card.get("code_version") or [])) or "?"


def run_by(card: Mapping[str, Any]) -> str:
    """``nearlight`` for a method run here, ``self-reported (<file>)`` for answers run elsewhere."""
    rep = card.get("self_reported")
    return f"self-reported ({rep.get('file', '?')})" if rep else "nearlight"


#: Column names of the scorecard metrics (others keep their own).
SHORT = {"lamp_position_error_pct": "lamp", "lamp_position_error_mm": "lamp", "lamp_position_error_m": "lamp",
         "direction_error_deg": "direction", "sigma_rel_error": "σ rel.", "ks_rel_error": "Ks rel."}  # fmt: skip
#: The metrics whose recall ladder the leaderboard shows: where the lamp is.
LAMP_LADDERS = ("lamp_", "direction_")


def _unit(metric: str) -> tuple[str, float]:
    """How a metric's thresholds and medians read: unit and scale, the scorecard's own (:data:`LADDERS`) when it
    has a ladder there, else from the name's suffix."""
    if metric in LADDERS:
        return f" {LADDERS[metric].unit}", LADDERS[metric].scale
    return (" %" if metric.endswith("_pct") else " mm" if metric.endswith("_mm") else " m" if metric.endswith("_m")
            else ""), 1.0  # fmt: skip


def rows(card: Mapping[str, Any]) -> list[Row]:
    """The leaderboard rows of one scorecard: one per group (category value), columns as the module says.

    Columns: method, version, run by; the recall at each threshold of every lamp metric (in % of cases);
    the median of every metric with its 95 % interval; the covariance's coverage with its interval; failed
    of n; the median run time (s) and the machine.
    """
    out = []
    metrics = list(card.get("thresholds", {}))
    for i, g in enumerate(card["groups"]):
        base = f"/groups/{i}"
        cells = {"method": Cell(str(card.get("method", "?")), sort=str(card.get("method", "?"))),
                 "version": Cell(version(card), sort=version(card)), "run by": Cell(run_by(card), sort=run_by(card))}
        for m in metrics:
            if not m.startswith(LAMP_LADDERS) or m not in g:
                continue
            unit, scale = _unit(m)
            for j, t in enumerate(card["thresholds"][m]):
                n = _number(card, f"{base}/{m}/recall/{j}", 100.0)
                cells[f"{SHORT.get(m, m)} ≤ {scale * t:g}{unit}: recall %"] = Cell("{}", (n,), n.value)
        for m in metrics:
            if m not in g:
                continue
            unit, scale = _unit(m) if m.startswith(LAMP_LADDERS) else ("", 1.0)
            med = _number(card, f"{base}/{m}/median", scale)
            lo, hi = (_number(card, f"{base}/{m}/median_ci95/{k}", scale) for k in (0, 1))
            cells[f"{SHORT.get(m, m)} error{unit}: median [95 %]"] = Cell("{} [{}, {}]", (med, lo, hi), med.value)
        if "covariance" in g:
            cov = [_number(card, f"{base}/covariance/{k}", 100.0) for k in ("coverage", "coverage_lo", "coverage_hi")]
            cells["covariance coverage % [95 %]"] = Cell("{} [{}, {}]", tuple(cov), cov[0].value)
        failed, n = _number(card, f"{base}/failed"), _number(card, f"{base}/n")
        cells["failed / cases"] = Cell("{} / {}", (failed, n), failed.value)
        if isinstance(card.get("runtime_s"), dict) and "median" in card["runtime_s"]:
            rt = _number(card, "/runtime_s/median")
            cells["run time s (median)"] = Cell("{}", (rt,), rt.value)
        cells["machine"] = Cell(str(card.get("machine", "?")), sort=str(card.get("machine", "?")))
        group = "all" if g.get("category") == "all" else f"{g.get('category')}={g.get('value')}"
        out.append(Row(group, cells))
    return out
